"""Native extensions. Everything else lives in pyproject.toml."""
from setuptools import setup

setup()
