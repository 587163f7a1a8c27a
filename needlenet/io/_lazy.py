"""Frame stacks read on access, so that a long recording need not fit in memory.

A :class:`FrameStack` stands in for a ``(T, H, W)`` or ``(T, Z, Y, X)`` uint8 array: it has
``shape``, ``dtype``, ``ndim``, ``len()`` and indexing, and frame ``i`` is read from disk (a
memory map, an image file, a video decoder) only when ``stack[i]`` asks for it. Selecting
frames (``stack[1:5]``, ``stack[mask]``) or cutting every frame (``stack[:, y0:y1, x0:x1]``)
gives another stack without reading anything. Code that needs every pixel at once
(``np.asarray(stack)``, ``stack.max()``, ``stack == other``) reads every frame into one array.

:func:`mapped_frames` reads uncompressed pixel data through a read-only memory map: each frame
is copied out when it is read and its pages are handed back to the kernel, so the resident
memory stays at a frame or two however long the recording is. :func:`inflated_frames` reads
frames out of one zlib or gzip stream (a compressed PLUS file, a gzip NRRD), inflating them in
order as they are read.
"""

from __future__ import annotations

import mmap
import os
from collections.abc import Callable

import numpy as np
from numpy.lib.mixins import NDArrayOperatorsMixin

__all__ = ["FrameStack", "mapped_frames", "is_frame_stack", "ZlibStream", "inflated_frames"]


def is_frame_stack(obj) -> bool:
    """Whether ``obj`` is a :class:`FrameStack` (frames read when indexed)."""
    return isinstance(obj, FrameStack)


class FrameStack(NDArrayOperatorsMixin):
    """A read-only stack of frames, frame ``i`` being ``read(i)`` (a new contiguous array of
    ``frame_shape`` and ``dtype``, its caller's to keep or change).

    ``source`` is what the frames come from (the memory-mapped array, the file list, the
    video's path), for the reader's caller; ``index`` maps this stack's frames to ``read``'s
    (a selection of frames) and ``stages`` are the per-frame cuts applied after ``read``."""

    def __init__(self, read: Callable[[int], np.ndarray], n_frames: int, frame_shape,
                 dtype=np.uint8, *, source=None, index: np.ndarray | None = None,
                 stages: tuple = ()):
        self._read = read
        self._frame_shape = tuple(int(s) for s in frame_shape)
        self._index = np.arange(int(n_frames)) if index is None else \
            np.asarray(index, np.intp)
        self._stages = tuple(stages)
        self.dtype = np.dtype(dtype)
        self.source = source
        probe = np.broadcast_to(np.zeros((), self.dtype), self._frame_shape)
        for st in self._stages:
            probe = probe[st]
        self.shape = (len(self._index), *probe.shape)

    # -- the array-like surface ------------------------------------------------------------
    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def nbytes(self) -> int:
        return self.size * self.dtype.itemsize

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"FrameStack(shape={self.shape}, dtype={self.dtype}, read on access)"

    def __iter__(self):
        for k in range(len(self)):
            yield self.frame(k)

    def frame(self, k: int) -> np.ndarray:
        """Frame ``k`` of this stack, read now: a contiguous array of its own."""
        f = self._read(int(self._index[k]))
        if not self._stages:
            return f
        for st in self._stages:
            f = f[st]
        return np.array(f, self.dtype, copy=True, order="C")

    def __getitem__(self, key):
        key = key if isinstance(key, tuple) else (key,)
        first, rest = key[0], key[1:]
        if isinstance(first, (int, np.integer)):
            k = int(first)
            if not -len(self) <= k < len(self):
                raise IndexError(f"frame {k} is out of range for {len(self)} frames")
            f = self.frame(k % len(self))
            return f[rest] if rest else f
        if first is Ellipsis and not rest:
            return self
        if first is Ellipsis or not all(isinstance(r, slice) for r in rest):
            return np.asarray(self)[key]  # a fancy per-pixel index: read every frame
        index = self._index[first]
        if index.ndim != 1:
            return np.asarray(self)[key]
        stages = self._stages + ((rest,) if rest else ())
        return FrameStack(self._read, 0, self._frame_shape, self.dtype, source=self.source,
                          index=index, stages=stages)

    def __array__(self, dtype=None, copy=None):
        out = np.empty(self.shape, self.dtype)
        for k in range(len(self)):
            out[k] = self.frame(k)
        return out if dtype is None else out.astype(dtype, copy=False)

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        inputs = tuple(np.asarray(x) if isinstance(x, FrameStack) else x for x in inputs)
        return getattr(ufunc, method)(*inputs, **kwargs)

    def __getattr__(self, name):
        # ndarray's methods (astype, max, reshape, tobytes, ...) on every frame read at once
        if not name.startswith("_") and hasattr(np.ndarray, name):
            return getattr(np.asarray(self), name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")


_DROP_MARGIN = 1 << 20  # bytes; more than the kernel's fault-around (64 KiB by default)


def mapped_frames(path: str | os.PathLike, offset: int, n_frames: int, frame_shape,
                  dtype, prepare: Callable[[np.ndarray], np.ndarray], out_shape,
                  out_dtype=np.uint8) -> FrameStack:
    """Frames stored one after another from byte ``offset`` of ``path`` (``n_frames`` of
    ``frame_shape`` in ``dtype``, C order), read through a read-only memory map.

    Frame ``i`` is ``prepare(raw_frame_i)`` (an array of ``out_shape`` and ``out_dtype``:
    colour to gray, the orientation's flips); after copying it out, the pages of its bytes
    are dropped from this process's memory (they stay in the kernel's file cache). The
    stack's ``source`` is the mapped array of every raw frame."""
    dtype = np.dtype(dtype)
    with open(path, "rb") as fh:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    raw = np.ndarray((int(n_frames), *frame_shape), dtype, buffer=mm, offset=int(offset))
    frame_bytes = int(np.prod(frame_shape)) * dtype.itemsize
    page = mmap.PAGESIZE
    can_drop = hasattr(mm, "madvise") and hasattr(mmap, "MADV_DONTNEED")

    def read(i: int) -> np.ndarray:
        out = np.array(prepare(raw[i]), order="C", copy=True)
        if can_drop:  # the kernel maps pages around a fault too: drop a margin either side
            a = max(int(offset) + i * frame_bytes - _DROP_MARGIN, 0) // page * page
            b = min(int(offset) + (i + 1) * frame_bytes + _DROP_MARGIN, len(mm))
            mm.madvise(mmap.MADV_DONTNEED, a, b - a)
        return out

    return FrameStack(read, n_frames, out_shape, out_dtype, source=raw)


class ZlibStream:
    """The bytes one zlib stream inflates to, from byte ``start`` of ``path`` (``length``
    compressed bytes), handed out in order: :meth:`next_bytes` inflates only what it returns
    (its input read 1 MiB at a time). A stream cut short gives what it holds, then nothing;
    damaged data raises ``zlib.error``."""

    def __init__(self, path: str | os.PathLike, start: int, length: int, wbits: int = 15):
        self.path, self.start, self.length = path, int(start), int(length)
        self.wbits = wbits  # zlib's: 15 a zlib stream, 15 + 16 a gzip one
        self._fh = None
        self.restart()

    def restart(self) -> None:
        """Back to the stream's first byte."""
        import zlib

        if self._fh is not None:
            self._fh.close()
        self._fh = open(self.path, "rb")
        self._fh.seek(self.start)
        self._left = self.length
        self._d = zlib.decompressobj(self.wbits)
        self._pending = bytearray()
        self._done = False
        self.pos = 0  # bytes handed out so far

    def next_bytes(self, n: int) -> bytes:
        """The next ``n`` inflated bytes (fewer at the stream's end)."""
        out = self._pending[:n]
        del self._pending[:n]
        while len(out) < n and not self._done:
            if self._d.eof:
                self._done = True
                break
            chunk = self._d.unconsumed_tail
            if not chunk and self._left > 0:
                chunk = self._fh.read(min(1 << 20, self._left))
                self._left -= len(chunk)
            if not chunk:  # the input ends before the stream does: what zlib still holds
                self._pending += self._d.flush()
                self._done = True
                take = self._pending[:n - len(out)]
                del self._pending[:len(take)]
                out += take
                break
            out += self._d.decompress(chunk, n - len(out))
        self.pos += len(out)
        return bytes(out)

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def __del__(self):
        self.close()


def inflated_frames(stream: ZlibStream, n_frames: int, frame_shape, dtype,
                    prepare: Callable[[np.ndarray], np.ndarray], out_shape, src: str,
                    out_dtype=np.uint8, skip: int = 0) -> FrameStack:
    """Frames stored one after another in a zlib stream from its inflated byte ``skip``,
    inflated when read: frame ``i`` after frame ``i - 1`` inflates one frame, a frame further
    on inflates (and drops) the ones between, an earlier one starts the stream again. Frame
    ``i`` is ``prepare(raw_frame_i)``, as in :func:`mapped_frames`."""
    import zlib

    from ._errors import RecordingError

    dtype = np.dtype(dtype)
    frame_bytes = int(np.prod(frame_shape)) * dtype.itemsize

    def read(i: int) -> np.ndarray:
        at = int(skip) + i * frame_bytes
        try:
            if stream.pos > at:
                stream.restart()
            while stream.pos < at:
                if not stream.next_bytes(min(1 << 20, at - stream.pos)):
                    break
            data = stream.next_bytes(frame_bytes) if stream.pos == at else b""
        except (zlib.error, OSError) as exc:
            raise RecordingError(f"{src}: frame {i}: compressed pixel data is damaged "
                                 f"({exc})") from None
        if len(data) != frame_bytes:
            raise RecordingError(f"{src}: frame {i}: the compressed pixel data ends before it "
                                 "(the file changed since it was opened?)")
        raw = np.frombuffer(data, dtype).reshape(frame_shape)
        return np.array(prepare(raw), order="C", copy=True)

    return FrameStack(read, n_frames, out_shape, out_dtype, source=stream)
