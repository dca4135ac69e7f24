"""Reading input files and writing output files safely.

* Inputs (graph files, TLEs, tables) are read only if they are regular files (a FIFO or a
  device would block or never end), no larger than a stated limit, and valid UTF-8 text;
  anything else is one :class:`UserError` naming the file, never its contents.
* Outputs (exports, images) are written to a temporary name beside the final one and
  renamed when complete, so a failed or interrupted write never leaves a partial file
  under the final name; an existing file is replaced only when asked.
* Every OS error becomes one line naming the file and what went wrong.
"""

from __future__ import annotations

import errno
import math
import os
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from .errors import UserError

#: the largest text input read (TLE files, tables) [bytes]
MAX_TEXT_BYTES = 16 << 20


class FileProblem(UserError):
    """An input file that cannot be read as asked: its path and the reason (never its contents)."""

    def __init__(self, path: str | Path, reason: str):
        super().__init__(f"{path}: {reason}")
        self.path, self.reason = str(path), reason

_WHAT = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "no such file or folder",
    errno.ENOTDIR: "a part of the path is not a folder",
    errno.EISDIR: "is a folder, not a file",
    errno.ENAMETOOLONG: "file name too long",
    errno.EMFILE: "too many open files",
    errno.EIO: "input/output error",
}


def os_reason(exc: OSError) -> str:
    """What went wrong, in words (``no space left on the device``)."""
    return _WHAT.get(exc.errno or -1) or exc.strerror or type(exc).__name__


def describe_os_error(exc: OSError) -> str:
    """One line for an OS error: the file and what went wrong (no traceback)."""
    return f"{exc.filename}: {os_reason(exc)}" if exc.filename is not None else os_reason(exc)


def file_kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_regular_file(path: str | Path, what: str = "file", max_bytes: int | None = MAX_TEXT_BYTES) -> Path:
    """``path`` if it is an existing regular file of at most ``max_bytes``; else one UserError.

    Checked with ``stat`` before anything opens it: opening a FIFO would block.
    """
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise FileProblem(path, f"{what} not found") from None
    except OSError as exc:
        raise FileProblem(path, f"cannot read the {what} ({os_reason(exc)})") from None
    if not stat.S_ISREG(info.st_mode):
        raise FileProblem(path, f"expected a {what}, found {file_kind(info.st_mode)}")
    if max_bytes is not None and info.st_size > max_bytes:
        raise FileProblem(path, f"the {what} is {_size(info.st_size)}, more than the {_size(max_bytes)} a {what} "
                                f"may have")
    return path


def _size(nbytes: int) -> str:
    return f"{nbytes / 2**20:.1f} MiB" if nbytes >= 2**20 else f"{nbytes / 1024:.0f} kiB"


def read_text(path: str | Path, what: str = "file", max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes``; one UserError otherwise (never its contents)."""
    path = check_regular_file(path, what, max_bytes)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        with os.fdopen(fd, "rb") as handle:
            if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):   # swapped since the check
                raise FileProblem(path, f"expected a {what}, found something else")
            data = handle.read(max_bytes + 1)
    except OSError as exc:
        raise FileProblem(path, f"cannot read the {what} ({os_reason(exc)})") from None
    if len(data) > max_bytes:
        raise FileProblem(path, f"the {what} is larger than {_size(max_bytes)}")
    if b"\0" in data:
        raise FileProblem(path, f"the {what} is binary, not text")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise FileProblem(path, f"line {line}: the {what} is not UTF-8 text") from None


def check_free_space(path: str | Path, needed_bytes: int, what: str = "output file") -> None:
    """Refuse to start writing ``needed_bytes`` (an upper estimate) where the disk has less free space:
    some writers (HDF5) cannot fail cleanly when the disk fills up mid-file."""
    folder = Path(path).parent
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if needed_bytes > free:
        raise UserError(f"{path}: the {what} needs up to {needed_bytes / 1e6:.1f} MB but the disk of {folder} "
                        f"has {free / 1e6:.1f} MB free; free some space or write elsewhere")


def check_output_path(path: str | Path, overwrite: bool, what: str = "output file") -> Path:
    """Refuse an output path that cannot be written, before any work: a missing or read-only folder,
    a folder or special file in the way, or an existing file without ``overwrite``."""
    path = Path(path)
    parent = path.parent
    if not parent.is_dir():
        problem = "does not exist" if not parent.exists() else "is not a folder"
        raise UserError(f"{path}: cannot write the {what}: folder {parent} {problem}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{path}: cannot write the {what}: folder {parent} is not writable")
    if path.exists() or path.is_symlink():
        info = path.lstat()
        if not stat.S_ISREG(info.st_mode):
            raise UserError(f"{path}: cannot write the {what}: {file_kind(info.st_mode)} is in the way")
        if not overwrite:
            raise UserError(f"{path} already exists; pass --overwrite to replace it")
    from .store import is_run_store

    for folder in path.resolve().parents:
        if is_run_store(folder):
            raise UserError(f"{path}: cannot write the {what} inside the run store {folder}")
    return path


@contextmanager
def atomic_output(path: str | Path, overwrite: bool = False, what: str = "output file",
                  suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` to write; rename it to ``path`` when the block
    completes, remove it if it fails. Checks the path first (:func:`check_output_path`).

    The temporary name ends with ``suffix`` (default: ``path``'s extension), for writers that
    choose a format by the extension.
    """
    path = check_output_path(path, overwrite, what)
    temporary = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix if suffix is None else suffix}")
    try:
        try:
            yield temporary
        except OSError as exc:
            if exc.filename is not None and Path(exc.filename) == temporary:
                raise UserError(f"{path}: cannot write the {what} ({os_reason(exc)})") from None
            raise
        if not temporary.exists():
            raise UserError(f"{path}: nothing was written")
        if path.exists() and not overwrite:      # appeared while we wrote
            raise UserError(f"{path} already exists; pass --overwrite to replace it")
        os.replace(temporary, path)
    except BaseException:
        try:
            temporary.unlink()
        except OSError:
            pass
        raise


#: the resolutions a figure may be saved at [dots per inch]
FIGURE_DPI_RANGE = (10.0, 2400.0)


def check_figure_output(path: str | Path, overwrite: bool, dpi: float) -> str:
    """Refuse, before any work, a figure that cannot be saved as asked: a resolution out of range, an
    extension matplotlib cannot write (the format follows it; none means PNG), or a bad output path
    (:func:`check_output_path`). Returns the format (``png``, ``pdf``, ``svg`` ...)."""
    low, high = FIGURE_DPI_RANGE
    if not (math.isfinite(dpi) and low <= dpi <= high):
        raise UserError(f"--dpi must be between {low:g} and {high:g}, got {dpi:g}")
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    from matplotlib.backend_bases import FigureCanvasBase

    known = FigureCanvasBase.get_supported_filetypes()
    if fmt not in known:
        raise UserError(f"{path}: cannot write a figure as .{fmt[:20]}; the extension gives the format, one of "
                        f"{', '.join(sorted(known))}")
    check_output_path(path, overwrite, "figure")
    return fmt


def save_figure(figure, path: str | Path, overwrite: bool, dpi: float) -> None:
    """Save a matplotlib Figure to ``path`` (format from its extension) through a temporary name, so a
    failed save leaves no partial file; checked first as :func:`check_figure_output`."""
    fmt = check_figure_output(path, overwrite, dpi)
    with atomic_output(path, overwrite, "figure", suffix=f".{fmt}") as temporary:
        figure.savefig(temporary, dpi=dpi, format=fmt)
