"""Atomic output and located input: every file lidarcat writes or reads goes through here.

Every file lidarcat writes goes through :func:`atomic_write` (or
:func:`atomic_dir`) so that an interrupted or failed run never leaves a partial
file behind: content is written to a temporary file in the destination folder
and renamed into place with :func:`os.replace`, which is atomic on POSIX.
Inputs are read by :func:`read_bytes` / :func:`read_text`, whose errors name the file.

The output folder is a boundary.  A name that comes from input data (a photo,
point, sheet, tile or job id) becomes part of a path only through
:func:`safe_component`, which refuses anything that is not one plain file name.
Within :func:`output_root` every :func:`atomic_write`, :func:`atomic_dir` and
:func:`remove_below` checks with :func:`inside` that its path stays in the
output folder and that nothing below the folder on the way is a symbolic link:
a link shipped in (or planted into) an output folder is refused, never followed.
"""

from __future__ import annotations

import contextlib
import contextvars
import hashlib
import io
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any


from ..errors import LidarcatError, ProductError, SurveyError, location

__all__ = ['provenance', 'atomic_write', 'atomic_dir', 'folder_lock', 'write_text_atomic', 'file_sha256', 'read_bytes',
           'read_text', 'safe_component', 'inside', 'output_root', 'remove_below']

#: longest name :func:`safe_component` passes, in UTF-8 bytes: a prefix, a suffix and the ``.NAME.XXXX.part``
#: of an atomic write still fit the 255 bytes of a file name
MAX_COMPONENT_BYTES = 160

_ROOT: contextvars.ContextVar[Path | None] = contextvars.ContextVar("lidarcat_output_root", default=None)


def _excerpt(text: str, n: int = 40) -> str:
    """A short, escaped excerpt of *text* for an error message (never the whole input)."""
    shown = text if len(text) <= n else text[:n] + "..."
    return repr(shown)


def safe_component(text: object, what: str, source: object = None,
                   error: type[LidarcatError] = SurveyError) -> str:
    """*text* when it is one plain file name; otherwise an error naming the id and where it came from.

    A name from input data (a photo, point, sheet, tile or job id) becomes part of an output path only
    through here.  It must not be empty, ``.`` or ``..``, nor start with ``.`` (hidden files, and the
    ``.stages``/``.part`` names of the output folder), nor hold ``/``, ``\\``, NUL or another control
    character, and must fit :data:`MAX_COMPONENT_BYTES` bytes of UTF-8.  Such ids are refused rather
    than mapped to another name: a mapped name would no longer be the id the user looks for, two ids
    could map to one file, and an id like ``x/../../pwn`` is a mistake or an attack, never a photo name.

    Parameters
    ----------
    text : str
        The name.
    what : str
        What it is (``photo id``, ``sheet name``, ...), for the message.
    source : path or str, optional
        Where it was read (a file, ``file:line``), for the message.
    error : LidarcatError subclass
        The class raised (``SurveyError`` by default: the input is at fault).

    >>> safe_component("IMG_0042", "photo id")
    'IMG_0042'
    >>> safe_component("x/../../pwn", "photo id", "photos.csv")
    Traceback (most recent call last):
    ...
    lidarcat.errors.SurveyError: photos.csv: photo id 'x/../../pwn' cannot name an output file: it holds '/'; ...
    """
    name = str(text)
    why = None
    if name in ("", ".", ".."):
        why = "it is empty" if not name else f"it is {name!r}"
    elif name.startswith("."):
        why = "it starts with '.'"
    else:
        bad = next((c for c in name if c in "/\\" or ord(c) < 32 or ord(c) == 127), None)
        if bad is not None:
            why = f"it holds {bad!r}"
        elif len(name.encode("utf-8", "surrogatepass")) > MAX_COMPONENT_BYTES:
            why = f"it is longer than {MAX_COMPONENT_BYTES} bytes"
    if why is None:
        return name
    where = f"{source}: " if source is not None else ""
    raise error(f"{where}{what} {_excerpt(name)} cannot name an output file: {why}; "
                f"use letters, digits, '_', '-', '.' (not first)")


def inside(root: str | os.PathLike, path: str | os.PathLike, *, error: type[LidarcatError] = ProductError) -> Path:
    """*path*, checked to lie in the output folder *root* with no symbolic link below *root* on the way.

    The check is lexical (``..`` is resolved on the text, links are not followed) and then looks at
    every existing component from the first one below *root* down to *path* itself: a symbolic link
    there would send a write, rename or delete elsewhere, so it is refused.  *root* itself may be a link
    (the user chose it).

    Raises
    ------
    LidarcatError
        Of class *error*: ``PATH: outside the output folder ROOT`` or ``LINK: a symbolic link in the
        output folder (to TARGET); lidarcat does not write through links: remove it``.
    """
    root_abs = Path(os.path.normpath(os.path.abspath(root)))
    p = Path(os.path.normpath(os.path.abspath(path)))
    try:
        rel = p.relative_to(root_abs)
    except ValueError:
        raise error(f"{path}: outside the output folder {root}; lidarcat writes only inside it") from None
    cur, shown = root_abs, Path(root)
    for part in rel.parts:
        cur, shown = cur / part, shown / part
        if cur.is_symlink():
            try:
                target = os.readlink(cur)
            except OSError:
                target = "?"
            raise error(f"{shown}: a symbolic link in the output folder {root} (to {target}); lidarcat does "
                        f"not write or delete through links: remove it")
        if not cur.exists():
            break
    return Path(path)


def _check(path: Path) -> None:
    root = _ROOT.get()
    if root is not None:
        inside(root, path)


@contextlib.contextmanager
def output_root(root: str | os.PathLike) -> Iterator[Path]:
    """Within the block, every :func:`atomic_write`, :func:`atomic_dir` and :func:`remove_below` of this
    thread checks (:func:`inside`) that its path stays in *root*; *root* itself is checked first."""
    root = Path(root)
    outer = _ROOT.get()
    if outer is not None:
        inside(outer, root)
    token = _ROOT.set(root)
    try:
        yield root
    finally:
        _ROOT.reset(token)


def remove_below(folder: str | os.PathLike, keep: Iterable[str] = (), *, skip_parts: bool = True) -> None:
    """Remove the files under *folder* but those in *keep* (paths relative to *folder*), then empty folders.

    Never follows a link: *folder* must not be one (:func:`inside` its output root); a link found below it
    is removed as a name, its target is left alone.  ``*.part`` names (a concurrent atomic write) are kept
    when *skip_parts*.  *folder* itself goes when it ends up empty and nothing was kept.
    """
    folder = Path(folder)
    _check(folder)
    if folder.is_symlink():
        inside(folder.parent, folder)  # refuse even outside an output_root block
    if not folder.is_dir():
        return
    keep = set(keep)

    def walk(d: Path, rel: str) -> None:
        with os.scandir(d) as it:
            entries = list(it)
        for e in entries:
            r = f"{rel}{e.name}"
            if e.is_dir(follow_symlinks=False):
                walk(Path(e.path), r + "/")
                with contextlib.suppress(OSError):
                    if not any(os.scandir(e.path)):
                        os.rmdir(e.path)
            elif r not in keep and not (skip_parts and ".part" in e.name):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(e.path)

    walk(folder, "")
    if not keep and not any(os.scandir(folder)):
        with contextlib.suppress(OSError):
            folder.rmdir()


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", **kwargs: Any) -> Iterator[io.IOBase]:
    """Open a temporary file next to *path*; rename it onto *path* on success.

    On an exception (including ``KeyboardInterrupt``) the temporary file is
    removed and *path* is left untouched.
    """
    path = Path(path)
    _check(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    try:
        if "b" not in mode:
            kwargs.setdefault("encoding", "utf-8")
            kwargs.setdefault("newline", "")
        with open(tmp, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Build a whole output folder in a temporary sibling, then move it into place.

    Files already in *path* that the new run does not write are kept; files it
    does write replace the old ones only once every file has been written.
    """
    path = Path(path)
    _check(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent))
    try:
        yield tmp
        _check(path)  # again: the stage may have run long
        path.mkdir(parents=True, exist_ok=True)
        for item in sorted(tmp.rglob("*")):
            if item.is_file() and not item.is_symlink():
                dest = path / item.relative_to(tmp)
                _check(dest)
                dest.parent.mkdir(parents=True, exist_ok=True)
                os.replace(item, dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, what: str = "lidarcat run") -> Iterator[Path]:
    """Hold ``FOLDER/.lidarcat.lock`` while a run writes into *folder*.

    Two runs writing one output folder would interleave their stage outputs;
    the second one stops with an error naming the first (its pid, host and
    start time).  A lock left by a run that died on this host (its pid is gone)
    is taken over; one from another host must be removed by hand (the message
    says so).  The lock is removed on exit, also on Ctrl-C.

    Raises
    ------
    LidarcatError
        The folder is in use by another run.
    """
    import datetime
    import socket

    from ..errors import LidarcatError

    lock = Path(folder) / ".lidarcat.lock"
    inside(folder, lock)  # a lock shipped as a link is neither read through nor taken over
    host = socket.gethostname()
    me = f"pid={os.getpid()} host={host} started={datetime.datetime.now().isoformat(timespec='seconds')}\n"
    for _attempt in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                info = dict(kv.split("=", 1) for kv in lock.read_text().split() if "=" in kv)
            except OSError:
                info = {}
            pid = int(info["pid"]) if info.get("pid", "").isdigit() else 0
            if info.get("host") == host and pid and not _pid_alive(pid):
                lock.unlink(missing_ok=True)  # left by a run that died: take it over
                continue
            raise LidarcatError(
                f"{folder}: in use by another {what} (pid {info.get('pid', '?')} on "
                f"{info.get('host', '?')}, started {info.get('started', '?')}); wait for it to finish "
                f"or choose another output folder; if no run is active, delete {lock}") from None
        with os.fdopen(fd, "w") as fh:
            fh.write(me)
        break
    try:
        yield lock
    finally:
        lock.unlink(missing_ok=True)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # signal 0: existence check only (PermissionError: alive, not ours)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write *text* (UTF-8) to *path* atomically and return the path."""
    with atomic_write(path, "w", newline="\n") as fh:
        fh.write(text)
    return Path(path)


def file_sha256(path: str | os.PathLike, chunk: int = 1 << 20) -> str:
    """SHA-256 (hex) of a file's content, read in chunks of *chunk* bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            h.update(block)
    return h.hexdigest()


def read_bytes(path: str | os.PathLike, error: type[LidarcatError] = SurveyError) -> bytes:
    """The content of an input file.

    Raises
    ------
    LidarcatError
        Of class *error* (e.g. ``TileIOError`` for a tile): ``PATH: file not
        found`` or ``PATH: cannot read (REASON)``.
    """
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except OSError as ex:
        raise error(f"{path}: cannot read ({ex.strerror})") from ex


def read_text(path: str | os.PathLike, error: type[LidarcatError] = SurveyError) -> str:
    r"""Read a UTF-8 text input file (a leading byte-order mark is dropped).

    Raises
    ------
    LidarcatError
        Of class *error*: the file is missing, unreadable, or not UTF-8 (the
        message names the line of the first bad byte and says to save as UTF-8).

    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     p = Path(folder) / "pontos.csv"
    ...     _ = p.write_bytes(b"photo,point\n1,Pra\xe7a\n")  # Latin-1, as old spreadsheets save
    ...     read_text(p)
    Traceback (most recent call last):
    ...
    lidarcat.errors.SurveyError: ...pontos.csv:2: byte 0xe7 is not UTF-8 text; save the file as UTF-8
    """
    path = Path(path)
    data = read_bytes(path, error)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as ex:
        line = ex.object.count(b"\n", 0, ex.start) + 1
        raise error(f"{location(path, line)}: byte 0x{ex.object[ex.start]:02x} is not UTF-8 text; "
                    f"save the file as UTF-8") from None


def provenance(inputs: Mapping[str, str | os.PathLike], parameters: Mapping[str, Any],
               root: str | os.PathLike | None = None) -> dict[str, Any]:
    """What an output was made from: ``{"lidarcat_version", "inputs", "parameters"}``.

    *inputs* maps a role (``photos``, ``survey.toml``, ...) to a file read;
    each becomes ``{"path", "sha256"}`` with the path relative to *root* when
    it lies inside it (outputs do not change with the folder they are made
    in).  No clock time: a rerun writes the same bytes.
    """
    from .. import __version__

    files = {}
    for role, p in sorted(inputs.items()):
        p = Path(p)
        shown = p
        if root is not None:
            try:
                shown = p.resolve().relative_to(Path(root).resolve())
            except ValueError:
                pass
        files[str(role)] = {"path": shown.as_posix(), "sha256": file_sha256(p)}
    return {"lidarcat_version": __version__, "inputs": files, "parameters": dict(parameters)}
