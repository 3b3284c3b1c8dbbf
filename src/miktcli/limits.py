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
MAX_VIDEO_FRAMES = 3_000  # one video: 50 s at 60 fps, 150 s at 20 fps, minutes to render; streamed to the
# encoder, but `evaluate_policy` (the library) still holds its frames: 3,000 of 480×480 RGB ≈ 2 GB

# Files read from users (imports, statistics, teacher and checkpoint files).
MAX_JSON_BYTES = 16 * MiB  # --obs-stats and env spec files: a 100,000-dim mean and var take ~4 MB, a spec ~1 KB
MAX_SB3_DATA_BYTES = 64 * MiB  # SB3's `data` JSON: kilobytes, a few MB with serialized schedules and buffers
MAX_TENSOR_FILE_BYTES = 256 * MiB  # policy.pth, CleanRL models, teachers, checkpoints: these MLPs take ~100 KB
MAX_SMALL_MEMBER_BYTES = 64 * 1024  # a zip's version stamp and the like: a few bytes
MAX_METRICS_BYTES = 1024 * MiB  # metrics.jsonl: ~1.3 KB a row, 1.2 MB for 2M steps, ~650 MB at MAX_STEPS
MAX_METRICS_LINE_BYTES = 1 * MiB  # one iteration's row: ~1.3 KB, ~10 KB with many teachers and layers

MAX_MODEL_FILE_BYTES = 256 * MiB  # one MJCF file or mesh, texture, height field, skin: Menagerie's largest ~30 MB
MAX_MODEL_BYTES = 1024 * MiB  # all of a model's files together; MuJoCo holds them in memory several times over
MAX_CARRIED_MODEL_BYTES = 64 * MiB  # a spec and its model files that a run folder and each teacher file carry
# (registry/carried.py): Menagerie's robots take a few MB; copied once per run and held in memory with a teacher,
# a larger model stays where its spec lies

# Model sizes (checked before a run folder exists).
MAX_LAYER_WIDTH = 4096  # --hidden: the paper's layers are 64 wide; 4096x4096 is 64 MB of float32 per layer
MAX_LAYERS = 16  # hidden layers per network: the paper uses 2, deep MLP policies rarely pass 8
MAX_PARAMETERS = 50_000_000  # the student's policy and value together: 200 MB of float32, x4 with Adam's state
MAX_EPISODE_STEPS = 1_000_000  # a spec's time limit: 1,000x the paper's 1,000; one evaluation episode ~20 min


def check_count(what: str, value: int, maximum: int, minimum: int = 1) -> int:
    """`value` if it is a whole number within [minimum, maximum], else a one-line refusal naming the limit."""
    if isinstance(value, bool) or not isinstance(value, int) or not minimum <= value <= maximum:
        raise MiktError(f"{what} {value!r}: must be a whole number from {minimum:,} to {maximum:,}",
                        hint=LIMITS_HINT)
    return value


def check_model_size(obs_dim: int, act_dim: int, pi_hidden: list[int], vf_hidden: list[int]) -> None:
    """Refuse layer sizes that would not fit in memory, before torch tries to allocate them."""
    for hidden in (pi_hidden, vf_hidden):
        if len(hidden) > MAX_LAYERS or any(w > MAX_LAYER_WIDTH for w in hidden):
            raise MiktError(f"hidden sizes {hidden}: at most {MAX_LAYERS} layers of at most {MAX_LAYER_WIDTH:,} units",
                            hint=LIMITS_HINT)

    def parameters(hidden: list[int], out: int) -> int:
        sizes = [obs_dim, *hidden, out]
        return sum((a + 1) * b for a, b in zip(sizes, sizes[1:], strict=False))

    total = parameters(pi_hidden, act_dim) + parameters(vf_hidden, 1)
    if total > MAX_PARAMETERS:
        raise MiktError(f"hidden sizes {pi_hidden}/{vf_hidden}: {total:,} parameters on a {obs_dim}-dim observation, "
                        f"more than the {MAX_PARAMETERS:,} a student may have", hint=LIMITS_HINT)


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


def open_regular(path, what: str):
    """A regular file opened for reading in binary; anything else (a FIFO, a device such as /dev/zero, a
    socket) refused in one line. Opened without blocking first: opening a FIFO for reading otherwise waits,
    deaf to Ctrl-C, for a writer that never comes."""
    import os
    import stat

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as err:
        raise MiktError(f"{what}: cannot be read: {err.strerror or err}") from err
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        if stat.S_ISDIR(mode):
            raise MiktError(f"{what}: a folder, not a file")
        kind = ("a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
                else "a socket" if stat.S_ISSOCK(mode) else "a special file")
        raise MiktError(f"{what}: {kind}, not a regular file; mikt reads only regular files")
    os.set_blocking(fd, True)
    return os.fdopen(fd, "rb")


def require_regular_file(path, what: str) -> None:
    """Refuse anything but a regular file before a library that opens it itself (safetensors, MuJoCo) can
    block on it or read it without end."""
    open_regular(path, what).close()


def read_file_bounded(path, what: str, maximum: int) -> bytes:
    """A file's bytes, refused from its size first and while reading (devices like /dev/zero declare none)."""
    import os

    with open_regular(path, what) as f:
        size = os.fstat(f.fileno()).st_size
        check_declared_size(what, size, maximum)
        return read_bounded(f, what, maximum)


def read_lines_bounded(path, what: str, maximum: int, max_line: int):
    """A text file's lines (bytes, without their newline) one at a time: memory stays one line, the whole file
    is refused past `maximum` bytes and a line past `max_line`."""
    total = 0
    with open_regular(path, what) as f:
        while line := f.readline(max_line + 1):
            total += len(line)
            if total > maximum:
                raise MiktError(f"{what}: more than the {maximum:,} bytes this kind of file may take",
                                hint=LIMITS_HINT)
            if len(line) > max_line and not line.endswith(b"\n"):
                raise MiktError(f"{what}: a line of more than {max_line:,} bytes", hint=LIMITS_HINT)
            yield line.rstrip(b"\n")
