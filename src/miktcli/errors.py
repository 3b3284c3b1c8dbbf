"""The one exception type the CLI turns into a one-line `Error: ...` and exit code 1."""


class MiktError(Exception):
    """A known, user-facing failure: bad input, missing file, mismatched dimensions."""

    def __init__(self, message: str, hint: str | None = None):
        super().__init__(message)
        self.hint = hint
