"""The one exception type the CLI turns into a one-line `Error: ...` and exit code 1 (with the subtypes whose
cause the CLI names by its flag), and the one formatter for pydantic validation errors (cards, specs, grids,
options all read the same way)."""

from __future__ import annotations

import errno

from pydantic import ValidationError


class MiktError(Exception):
    """A known, user-facing failure: bad input, missing file, mismatched dimensions."""

    def __init__(self, message: str, hint: str | None = None):
        super().__init__(message)
        self.hint = hint


# Failures the CLI explains in terms of its flags: each type says which input caused it, so the mapping to a
# flag (cli/transfer.py) never depends on a message's wording.

class TeacherCountError(MiktError):
    """A method given fewer or more teachers than it takes."""

    def __init__(self, message: str, *, given: int, minimum: int, maximum: int | None):
        super().__init__(message)
        self.given, self.minimum, self.maximum = given, minimum, maximum


class TeacherMismatchError(MiktError):
    """A teacher contradicting what the call stated about it: `stated` names that input (`encoder_widths`,
    `hidden`); None when the teachers disagree with each other."""

    def __init__(self, message: str, *, stated: str | None):
        super().__init__(message)
        self.stated = stated


class MethodOptionError(MiktError):
    """A method option that its method's options model refuses (`option`: the field, when one is to blame)."""

    def __init__(self, message: str, *, method: str, option: str | None):
        super().__init__(message)
        self.method, self.option = method, option


class EnvKeywordError(MiktError, TypeError):
    """A keyword of `gym.make("mikt/NAME", ...)` that the env's spec decides; a TypeError too, as Python's own
    refusal of an unexpected keyword would be."""


_OS_HINTS = {
    errno.EACCES: "check the permissions of that path, or choose another --registry / --out",
    errno.EPERM: "check the permissions of that path, or choose another --registry / --out",
    errno.EROFS: "that file system is read-only: choose another --registry / --out",
    errno.ENOSPC: "the disk is full: free some space and run again (a run resumes with --resume)",
    errno.EDQUOT: "the disk quota is used up: free some space and run again (a run resumes with --resume)",
    errno.ENOTDIR: "a part of that path is a file, not a folder (is --registry or --out a file?)",
    errno.EEXIST: "something already exists at that path: choose another name",
    errno.EISDIR: "that path is a folder, not a file",
    errno.ENAMETOOLONG: "the path is too long: choose a shorter --registry, --out or name",
}


def describe_os_error(err: OSError) -> MiktError:
    """An operating-system failure (permissions, full disk, a file where a folder belongs) for users."""
    where = f": {err.filename}" if err.filename else ""
    return MiktError(f"{err.strerror or type(err).__name__}{where}", hint=_OS_HINTS.get(err.errno))


# Discriminator tags pydantic puts into locations of tagged unions; users never typed them.
_UNION_TAGS = {"centipede", "gymnasium"}


def describe_validation_error(err: ValidationError) -> str:
    """`field 'a.b': message` for the first problem, and how many more there are."""
    problems = err.errors()
    first = problems[0]
    loc = ".".join(str(p) for p in first["loc"] if p not in _UNION_TAGS) or "(root)"
    if first["type"] in ("union_tag_invalid", "union_tag_not_found"):
        field = first["ctx"]["discriminator"].strip("'")
        message = (f"field '{field}': missing" if first["type"] == "union_tag_not_found"
                   else f"field '{field}': unknown {field} '{first['ctx']['tag']}', expected one of "
                        f"{first['ctx']['expected_tags']}")
    else:
        message = f"field '{loc}': {first['msg']}"
    more = len(problems) - 1
    return message + (f" (and {more} more problem{'s' if more > 1 else ''})" if more else "")
