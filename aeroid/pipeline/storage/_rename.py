"""Publishing a written file under its final name in one step, refusing an existing
one: Linux's ``renameat2(RENAME_NOREPLACE)``, else a hard link, else a look and a
rename (file systems with neither)."""

from __future__ import annotations

import ctypes
import errno
import functools
import os
from typing import Any


def _place(tmp_dir: int, tmp: str, dir_fd: int, final: str) -> bool:
    """Move the written file `tmp` to `final` (names within the two open folders);
    False, and `tmp` left, when `final` exists.

    A plain rename would replace an existing entry: this one refuses (Linux's
    ``RENAME_NOREPLACE``, or elsewhere a hard link and then removing `tmp`).
    """
    moved = _rename_noreplace(tmp_dir, tmp, dir_fd, final)
    if moved is not None:
        return moved
    try:
        os.link(tmp, final, src_dir_fd=tmp_dir, dst_dir_fd=dir_fd, follow_symlinks=False)
    except FileExistsError:
        return False
    except OSError as exc:
        if exc.errno not in _NO_LINKS:
            raise
        # a file system without hard links: a rename after a look, which two
        # commits of one key at the same instant could both pass (their
        # results are the same; the digests would tell if they were not)
        try:
            os.stat(final, dir_fd=dir_fd, follow_symlinks=False)
            return False
        except FileNotFoundError:
            os.rename(tmp, final, src_dir_fd=tmp_dir, dst_dir_fd=dir_fd)
    else:
        os.unlink(tmp, dir_fd=tmp_dir)
    return True


@functools.lru_cache(maxsize=1)
def _renameat2() -> Any:
    """Linux's renameat2, or None where the C library has none (macOS, musl before 1.2.5)."""
    try:
        func = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    func.restype = ctypes.c_int
    return func


_RENAME_NOREPLACE = 1
_NOREPLACE_UNSUPPORTED: set[int] = set()  # st_dev of file systems that refused the flag


def _rename_noreplace(tmp_dir: int, tmp: str, dir_fd: int, final: str) -> bool | None:
    """Rename `tmp` to `final` unless `final` exists, in one system call: True when
    renamed, False when `final` exists, None where the system cannot (then a hard link
    does the same in two calls)."""
    func = _renameat2()
    if func is None:
        return None
    if _NOREPLACE_UNSUPPORTED and os.fstat(tmp_dir).st_dev in _NOREPLACE_UNSUPPORTED:
        return None
    if func(tmp_dir, os.fsencode(tmp), dir_fd, os.fsencode(final), _RENAME_NOREPLACE) == 0:
        return True
    err = ctypes.get_errno()
    if err == errno.EEXIST:
        return False
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        _NOREPLACE_UNSUPPORTED.add(os.fstat(tmp_dir).st_dev)  # NFS, FUSE, old kernels
        return None
    raise OSError(err, os.strerror(err), final)


_NO_LINKS = {errno.EPERM, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EMLINK, errno.EXDEV}
