"""Typed exceptions. Library code raises these; only the CLI turns them into one-line messages and exit codes.

Every message says what was expected, what was found, and (where it helps) what to do.

Exit codes of ``photorecon``: 0 done; 1 other photorecon error; 2 bad argument or value (also every
command-line parse error); 3 input data; 4 no images; 5 SfM; 6 no depth (also: too little depth confirmed for a
usable mesh); 7 empty mesh; 8 output location; 9 texture; 10 an unexpected failure (a bug: ``-v`` shows the
traceback); 11 out of memory (a stage needs more than the free memory or the ``ulimit -v`` allows: the line
names the stage and its need; temporaries are removed); 130 interrupted (Ctrl-C, SIGINT);
143 terminated (SIGTERM); 141 stdout closed by its reader (``| head``), silently. Not photorecon's own, but
possible: 137 killed (SIGKILL, the system's out-of-memory killer), 134 / 139 a native library aborted or
crashed (almost always for lack of memory). An interrupted or killed run keeps no incomplete output and resumes
when run again.
"""
from __future__ import annotations

from ._disk import device, is_no_space, size_text


class PhotoreconError(Exception):
    """Base class. ``exit_code`` is the CLI's exit status for this failure class."""

    exit_code = 1


class BadArgumentError(PhotoreconError, ValueError):
    """An argument or input value has the wrong shape, type or range."""

    exit_code = 2


class InputDataError(PhotoreconError):
    """An input file or folder is missing, unreadable or inconsistent."""

    exit_code = 3


class NoImagesError(InputDataError):
    """The image folder holds no usable image."""

    exit_code = 4


class SfMError(PhotoreconError):
    """Structure-from-motion failed or registered too few images."""

    exit_code = 5


class NoDepthError(PhotoreconError):
    """No view produced a usable depth map."""

    exit_code = 6


class EmptyMeshError(PhotoreconError):
    """Fusion or cleaning left no triangle."""

    exit_code = 7


class OutputError(PhotoreconError):
    """The output location cannot be used (not empty, inside the input, not writable)."""

    exit_code = 8


def from_os_error(exc: OSError, out=None) -> PhotoreconError:
    """An ``OSError`` that escaped a stage as the photorecon error it stands for, naming the file: an
    ``OutputError`` when the file lies in the output folder ``out`` (or the disk is full), else an
    ``InputDataError``."""
    import errno
    from pathlib import Path

    name = exc.filename or "a file"
    what = exc.strerror or str(exc)
    inside_out = False
    if out is not None and exc.filename:
        try:
            inside_out = Path(exc.filename).resolve().is_relative_to(Path(out).resolve())
        except (OSError, ValueError):
            pass
    if is_no_space(exc):  # a full disk (numpy's short write has no errno nor file); the file may be a copy's source
        return no_space_error(out or exc.filename or ".")
    if inside_out or exc.errno == errno.EROFS:
        return OutputError(f"{name}: {what}; check the output folder's space and permissions")
    return InputDataError(f"{name}: {what}")


def no_space_error(path, need: int | None = None) -> OutputError:
    """The one-line error for a write to ``path`` that the disk could not hold (``need``: bytes it needed)."""
    needed = f"; about {size_text(need)} needed" if need else ""
    return OutputError(f"{path}: no space left on device {device(path)}{needed}; free some space or choose an "
                       "output folder on another device")


class TextureError(PhotoreconError):
    """Texturing is impossible: no view sees the mesh, or the atlas does not fit in memory or in its size."""

    exit_code = 9


class OutOfMemoryError(PhotoreconError):
    """A stage needs more memory than there is (the free memory, or the process's address-space limit,
    ``ulimit -v``): found before the stage starts where its need can be estimated, else when an allocation
    fails. The message names the stage and the memory it needs: ``out of memory in STAGE: needs about N GB
    (M GB available); try --quality preview or --max-size``."""

    exit_code = 11


MEMORY_HINT = "try --quality preview or --max-size"


def out_of_memory(stage: str, need: float | None = None, available: float | None = None,
                  hint: str = MEMORY_HINT) -> OutOfMemoryError:
    """The ``OutOfMemoryError`` of ``stage``: ``need`` and ``available`` in bytes (``need`` None: the stage's
    need is not known, only that it was more than was available)."""
    def size(b):
        return f"{b / 2**30:.1f} GB" if b >= 0.1 * 2**30 else f"{max(1, round(b / 2**20))} MB"

    if need is not None:
        what = f"needs about {size(need)}" + (f" ({size(available)} available)" if available is not None else "")
    else:
        what = f"needs more than the {size(available)} available" if available is not None else "needs more memory"
    return OutOfMemoryError(f"out of memory in {stage}: {what}; {hint}")


def is_out_of_memory(exc: BaseException) -> bool:
    """``exc`` is an allocation failure: Python's ``MemoryError`` (numpy's too, and pybind11's translation of
    C++'s ``std::bad_alloc`` in pycolmap and Open3D), a native library's error saying so, ``ENOMEM``, or a
    native library that could not be loaded for lack of address space ("failed to map segment")."""
    import errno

    if exc.__cause__ is not None or exc.__context__ is not None:  # "Cannot import the C++ backend" from ...
        if is_out_of_memory(exc.__cause__ or exc.__context__):
            return True
    if isinstance(exc, MemoryError):
        return True
    if isinstance(exc, OSError) and exc.errno == errno.ENOMEM:
        return True
    if isinstance(exc, (ImportError, OSError)):
        return "failed to map segment" in str(exc) or "cannot allocate memory" in str(exc).lower()
    if not isinstance(exc, RuntimeError):
        return False
    text = str(exc).lower()
    return any(k in text for k in ("bad_alloc", "out of memory", "cannot allocate memory", "failed to allocate",
                                   "memory allocation failed", "malloc"))


class InternalError(PhotoreconError):
    """An unexpected failure inside photorecon (a bug): the CLI says its type and message in one line; ``-v``
    shows the traceback."""

    exit_code = 10
