"""Every size limit on what users hand to mikt, in one place, each with why it is where it is.

The CLI and the library both check against these names (the library refuses, the CLI only reports), so a
limit is changed here or nowhere. Files are checked against the sizes they declare (zip headers, safetensors
headers, file sizes) before anything is read, and again while reading, so a file that lies about its size
still stops at the limit: memory stays bounded whatever a file claims."""

from __future__ import annotations

from miktcli.errors import MiktError

MiB = 1024 * 1024
LIMITS_HINT = "the limits and their reasons are listed in docs/guide/commands.md (Limits)"

# Training budgets (checked before a run folder exists).
MAX_STEPS = 1_000_000_000  # 500× the paper's 2M steps: about a month on one core at this engine's speed
MAX_NUM_ENVS = 256  # each env is a MuJoCo model stepped in this one process; the paper uses 1
MAX_ROUNDING = 2  # rounding --steps up to whole rollouts may at most double it (never a silent 2048× run)

# Evaluation and rendering.
MAX_EPISODES = 10_000  # evaluation episodes: ~10M env steps with 1,000-step episodes, hours on one core
MAX_VIDEO_FRAMES = 3_000  # frames are held in memory before encoding: 3,000 of 480×480 RGB ≈ 2 GB, 150 s at 20 fps

# Files read from users (imports, statistics, teacher and checkpoint files).
MAX_JSON_BYTES = 16 * MiB  # --obs-stats and env spec files: a 100,000-dim mean and var take ~4 MB, a spec ~1 KB
MAX_SB3_DATA_BYTES = 64 * MiB  # SB3's `data` JSON: kilobytes, a few MB with serialized schedules and buffers
MAX_TENSOR_FILE_BYTES = 256 * MiB  # policy.pth, CleanRL models, teachers, checkpoints: these MLPs take ~100 KB
MAX_SMALL_MEMBER_BYTES = 64 * 1024  # a zip's version stamp and the like: a few bytes


def check_count(what: str, value: int, maximum: int, minimum: int = 1) -> int:
    """`value` if it is a whole number within [minimum, maximum], else a one-line refusal naming the limit."""
    if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= maximum:
        raise MiktError(f"{what} {value!r}: must be a whole number from {minimum:,} to {maximum:,}",
                        hint=LIMITS_HINT)
    return value


def check_rounding(asked: int, planned: int, batch_size: int) -> None:
    """Refuse a budget that whole rollouts would more than double (--steps 5 would train 2,048 steps)."""
    if planned > MAX_ROUNDING * asked:
        raise MiktError(f"--steps {asked:,} would train {planned:,} steps: a rollout is {batch_size:,} steps, and "
                        f"rounding up to whole rollouts may at most double the request",
                        hint=f"ask for at least {-(-batch_size // MAX_ROUNDING):,} steps, or a multiple of "
                             f"{batch_size:,}")


def check_declared_size(what: str, size: int, maximum: int) -> None:
    if size > maximum:
        raise MiktError(f"{what}: {size:,} bytes, more than the {maximum:,} this kind of file may take",
                        hint=LIMITS_HINT)


def read_bounded(stream, what: str, maximum: int) -> bytes:
    """Read a stream to its end, refusing it as soon as it passes `maximum` bytes (never more in memory)."""
    data = stream.read(maximum + 1)
    if len(data) > maximum:
        raise MiktError(f"{what}: more than the {maximum:,} bytes this kind of file may take",
                        hint=LIMITS_HINT)
    return data


def read_file_bounded(path, what: str, maximum: int) -> bytes:
    """A file's bytes, refused from its size first and while reading (devices like /dev/zero declare none)."""
    import os

    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        check_declared_size(what, size, maximum)
        return read_bounded(f, what, maximum)
