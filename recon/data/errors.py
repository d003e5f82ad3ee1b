"""The one error type of prepared-dataset problems."""


class DatasetError(ValueError):
    """A prepared dataset is malformed; the message names the file and the problem."""
