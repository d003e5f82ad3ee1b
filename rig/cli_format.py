"""argparse help that shows defaults and keeps the epilog's examples on their own lines."""
import argparse


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    pass
