"""Exceptions raised by gpjax.

Every error caused by what a user supplied (a file, a column name, a configuration value,
a model file) derives from :class:`UserInputError`; the command line turns those into one
line on stderr and exit status 2. Anything else is a bug and keeps its traceback.
"""


class UserInputError(ValueError):
    """Something the user supplied is wrong; the message names the problem and the fix."""


class DataError(UserInputError):
    """A measurement file or array cannot be used (missing column, NaN, bad time axis, …)."""


class ConfigError(UserInputError):
    """A configuration value or file is invalid (unknown key, wrong type, bad range, …)."""


class ModelFileError(UserInputError):
    """A model file (``model.json``) is malformed or holds an expression outside the whitelist."""
