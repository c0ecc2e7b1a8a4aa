"""Outputs as a unit: a scan's files are all replaced, or none is.

A scan writes a cloud, its sidecar and optionally a raw-record folder. They are
first written in full to temporary names beside their targets (where a full disk
or a bad folder shows up, before any old output is touched); then each target
is moved aside and the new file moved in, with Ctrl-C and SIGTERM held back
until the swap is done. If a move fails, the old outputs are put back. A file of
an earlier run that was killed mid-write (``.NAME.plantsim-*``) is removed and
said so. Every disk error names its path.

Outputs never overwrite inputs: :func:`refuse_inputs` stops a run whose output
is one of its input files (the mesh, the configuration, the journal being resumed).
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import signal
import threading
from pathlib import Path

log = logging.getLogger(__name__)

_TMP_TAG = "plantsim-new"
_OLD_TAG = "plantsim-old"


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def refuse_inputs(outputs: dict[str, str | os.PathLike], inputs: dict[str, str | os.PathLike | None]) -> None:
    """Raises ValueError when an output path is an input's path (or the same file).

    Args:
      outputs: what each output is called (``{"cloud": "scan.las", ...}``).
      inputs: what each input is called, None where there is none.
    """
    for out_name, out_path in outputs.items():
        for in_name, in_path in inputs.items():
            if in_path is not None and _same(Path(out_path), Path(in_path)):
                raise ValueError(f"the {out_name} output {out_path} is the {in_name} this run reads; "
                                 f"choose another output path (nothing was written)")


def _temp_name(target: Path, tag: str) -> Path:
    return target.with_name(f".{target.name}.{tag}-{os.getpid()}")


def clean_stale(targets: list[Path]) -> list[Path]:
    """Removes temporary files an earlier, killed run left beside ``targets``; returns them."""
    removed = []
    for target in targets:
        parent = target.parent if str(target.parent) else Path(".")
        if not parent.is_dir():
            continue
        for path in parent.glob(f".{target.name}.plantsim-*"):
            pid = path.name.rsplit("-", 1)[-1]
            if pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid)):
                continue  # another run is writing right now
            if path.name.startswith(f".{target.name}.{_OLD_TAG}") and not target.exists():
                # The earlier run died between moving the old output aside and the new one in.
                os.replace(path, target)
                log.warning("restored %s from %s, left by a run that was killed while replacing it", target, path)
            else:
                _remove(path)
                log.warning("removed %s, left by an earlier run that was killed while writing %s", path, target)
            removed.append(path)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


@contextlib.contextmanager
def _signals_held():
    """Holds SIGINT and SIGTERM back until the block is done (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []

    def hold(signum, frame):
        caught.append(signum)

    previous = {sig: signal.signal(sig, hold) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in caught:
            if sig == signal.SIGINT:
                raise KeyboardInterrupt
            os.kill(os.getpid(), sig)


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as handle:
        os.fsync(handle.fileno())


class OutputSet:
    """Files to replace together. Stage each, then :meth:`commit` (or :meth:`discard`).

    Use as a context manager: leaving the block without committing discards the
    staged files and leaves the old outputs untouched.
    """

    def __init__(self):
        self._staged: list[tuple[Path, Path]] = []  # (temporary, target)
        self._workdirs: list[Path] = []

    def stage_bytes(self, target: str | os.PathLike, data: bytes) -> Path:
        """Writes ``data`` in full (and fsyncs it) to a temporary file beside ``target``."""
        target = Path(target)
        clean_stale([target])
        tmp = _temp_name(target, _TMP_TAG)
        try:
            with open(tmp, "wb") as handle:
                umask = os.umask(0)
                os.umask(umask)
                os.fchmod(handle.fileno(), 0o666 & ~umask)
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
        except OSError as exc:
            _remove(tmp)
            raise OSError(exc.errno, f"could not write {target}: {exc.strerror}", str(target)) from exc
        self._staged.append((tmp, target))
        return tmp

    def stage_folder(self, target: str | os.PathLike) -> Path:
        """A path, not yet existing, to build a folder output at (e.g. a bag), named like ``target``.

        It lies in a private folder beside ``target``, so that what is built
        there already has its final name when it is moved in.
        """
        target = Path(target)
        clean_stale([target])
        work = _temp_name(target, _TMP_TAG)
        _remove(work)
        try:
            work.mkdir()
        except OSError as exc:
            raise OSError(exc.errno, f"could not write {target}: {exc.strerror}", str(target)) from exc
        self._workdirs.append(work)
        self._staged.append((work / target.name, target))
        return work / target.name

    def commit(self) -> None:
        """Moves every staged file into place; on any failure puts the old outputs back."""
        moved_aside: list[tuple[Path, Path]] = []  # (backup, target)
        moved_in: list[Path] = []
        with _signals_held():
            try:
                for tmp, target in self._staged:
                    if target.exists() or target.is_symlink():
                        backup = _temp_name(target, _OLD_TAG)
                        _remove(backup)
                        os.replace(target, backup)
                        moved_aside.append((backup, target))
                    os.replace(tmp, target)
                    moved_in.append(target)
            except OSError as exc:
                for target in moved_in:
                    _remove(target)
                lost = []
                for backup, target in moved_aside:
                    try:
                        os.replace(backup, target)
                    except OSError:
                        lost.append(f"{target} (kept as {backup})")
                self.discard()
                path = exc.filename or "the outputs"
                state = ("the earlier outputs are unchanged" if not lost else
                         "could not put back " + ", ".join(lost) + "; move them back by hand")
                raise OSError(exc.errno, f"could not replace {path}: {exc.strerror}; {state}", str(path)) from exc
            for backup, _ in moved_aside:
                _remove(backup)
            self._staged = []
            self._clean_workdirs()

    def _clean_workdirs(self) -> None:
        for work in self._workdirs:
            _remove(work)
        self._workdirs = []

    def discard(self) -> None:
        """Removes the staged files (the old outputs are untouched)."""
        for tmp, _ in self._staged:
            _remove(tmp)
        self._staged = []
        self._clean_workdirs()

    def __enter__(self) -> "OutputSet":
        return self

    def __exit__(self, *exc) -> None:
        if self._staged or self._workdirs:
            self.discard()
