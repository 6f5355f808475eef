"""Exceptions raised by gpjax.

Every error caused by what a user supplied (a file, a column name, a configuration value,
a model file) derives from :class:`UserInputError`; the command line turns those into one
line on stderr and exit status 2. Anything else is a bug and keeps its traceback.
"""

from pathlib import Path


class UserInputError(ValueError):
    """Something the user supplied is wrong; the message names the problem and the fix."""


class DataError(UserInputError):
    """A measurement file or array cannot be used (missing column, NaN, bad time axis, …)."""


class ConfigError(UserInputError):
    """A configuration value or file is invalid (unknown key, wrong type, bad range, …)."""


class ModelFileError(UserInputError):
    """A model file (``model.json``) is malformed or holds an expression outside the whitelist."""


def read_user_file(path: str | Path, kind: str, error: type[UserInputError]) -> str:
    """Text of a file the user named; a missing or unreadable file raises ``error``."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{kind} {path} does not exist; check the path") from None
    except IsADirectoryError:
        raise error(f"{kind} {path} is a directory; give a file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise error(f"cannot read {kind} {path}: {err}") from None
