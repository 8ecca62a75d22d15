"""Masks of the height map: square (chessboard) erosion and dilation as runs of
whole-array boolean operations on shifted views — separable, ⌈log₂ width⌉ operations per
axis (SciPy's binary morphology and min/max filters on masks cost ~8× more on the height
maps) — 4- and 8-connected labelling, compiled (1.4× SciPy's on a height map, and with
each part's size or box), and what of a mask the border reaches (a flood fill: holes
without a labelling)."""

from __future__ import annotations

import numpy as np
from numba import njit


def _window_all(mask: np.ndarray, width: int, axis: int, outside: bool) -> np.ndarray:
    """out[i] = all(mask[i − width // 2 … i + width // 2]) along ``axis`` (odd ``width``),
    cells beyond the edge counting as ``outside``; in C order along either axis (the
    compiled passes that read the masks are compiled for, and read, rows)."""
    half = width // 2
    n = mask.shape[axis]

    def along(start: int | None, stop: int | None) -> tuple[slice, ...]:
        index = [slice(None)] * mask.ndim
        index[axis] = slice(start, stop)
        return tuple(index)

    shape = list(mask.shape)
    shape[axis] += 2 * half
    padded = np.full(shape, outside, dtype=bool)
    padded[along(half, half + n)] = mask
    # acc[i] = all(padded[i : i + span]); two overlapping spans cover a window.
    acc, span = padded, 1
    while span * 2 <= width:
        acc = acc[along(None, -span)] & acc[along(span, None)]
        span *= 2
    return acc[along(None, n)] & acc[along(width - span, width - span + n)]


def erode(mask: np.ndarray, radius: int) -> np.ndarray:
    """Cells of ``mask`` whose (2·radius + 1)² square lies in it (outside is not)."""
    width = 2 * radius + 1
    return _window_all(_window_all(mask, width, 0, False), width, 1, False)


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Cells within ``radius`` (chessboard) of a cell of ``mask``."""
    width = 2 * radius + 1
    return ~_window_all(_window_all(~mask, width, 0, True), width, 1, True)


@njit(cache=True, nogil=True)
def label4(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(labels, sizes): 4-connected parts of a 2-D ``mask`` numbered 1…n in the order
    their first cell comes in row-major order (as ``scipy.ndimage.label``), 0 outside;
    and the (n,) cells of each part.

    By runs of mask cells along the rows: a run joins every run of the row above that it
    overlaps, and the labels are written a run at a time at the end (a panel top's row is
    a few runs: 4× faster than a cell at a time on a height map)."""
    rows, cols = mask.shape
    most = rows * (cols // 2 + 1) + 1  # a run needs a gap before the next
    run_row = np.empty(most, np.int32)
    run_start = np.empty(most, np.int32)
    run_stop = np.empty(most, np.int32)
    run_label = np.empty(most, np.int32)
    parent = np.empty(most + 1, np.int32)
    n = runs = above = 0  # parts so far, runs so far, the first run of the row above
    for i in range(rows):
        first = runs
        j = 0
        while j < cols:
            if not mask[i, j]:
                j += 1
                continue
            start = j
            while j < cols and mask[i, j]:
                j += 1
            # The runs above that overlap [start, j): skip those ending before it.
            while above < first and run_stop[above] <= start:
                above += 1
            own, k = 0, above
            while k < first and run_start[k] < j:
                seen = _root(parent, run_label[k])
                if own == 0:
                    own = seen
                elif seen != own:  # parts meet: keep the older
                    parent[max(own, seen)] = min(own, seen)
                    own = min(own, seen)
                k += 1
            if own == 0:
                n += 1
                parent[n] = n
                own = n
            run_row[runs], run_start[runs], run_stop[runs], run_label[runs] = i, start, j, own
            runs += 1
        above = first
    final, count = _numbered(parent, n)
    labels = np.zeros((rows, cols), np.int32)
    sizes = np.zeros(count, np.int64)
    for r in range(runs):
        part = final[run_label[r]]
        labels[run_row[r], run_start[r] : run_stop[r]] = part
        sizes[part - 1] += run_stop[r] - run_start[r]
    return labels, sizes


@njit(cache=True, nogil=True)
def label8(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(labels, boxes): 8-connected parts of a 2-D ``mask`` numbered as ``label4``'s (and
    ``scipy.ndimage.label``'s with a 3 × 3 structure); and the (n, 4) (row0, col0, row1,
    col1) inclusive box of each, what ``scipy.ndimage.find_objects`` finds (4× faster
    than the two of them on a sparse mask). As ``label4``, with the two corners above."""
    rows, cols = mask.shape
    labels = np.zeros((rows, cols), np.int32)
    parent = np.empty(rows * cols // 2 + 2, np.int32)
    n = 0
    for i in range(rows):
        for j in range(cols):
            if not mask[i, j]:
                continue
            own = 0
            for di, dj in ((0, -1), (-1, -1), (-1, 0), (-1, 1)):  # the neighbours seen
                if i + di < 0 or not 0 <= j + dj < cols:
                    continue
                seen = labels[i + di, j + dj]
                if seen == 0 or seen == own:
                    continue
                if own == 0:
                    own = seen
                    continue
                a, b = _root(parent, own), _root(parent, seen)  # parts meet: keep the older
                parent[max(a, b)] = min(a, b)
                own = min(a, b)
            if own == 0:
                n += 1
                parent[n] = n
                own = n
            labels[i, j] = own
    final, count = _numbered(parent, n)
    boxes = np.empty((count, 4), np.int64)
    boxes[:, :2] = max(rows, cols)
    boxes[:, 2:] = -1
    for i in range(rows):
        for j in range(cols):
            if labels[i, j]:
                part = final[labels[i, j]]
                labels[i, j] = part
                box = boxes[part - 1]
                box[0], box[1] = min(box[0], i), min(box[1], j)
                box[2], box[3] = max(box[2], i), max(box[3], j)
    return labels, boxes


@njit(cache=True, nogil=True, inline="always")
def _root(parent: np.ndarray, k: int) -> int:
    while parent[k] != k:
        parent[k] = parent[parent[k]]  # path halving
        k = parent[k]
    return k


@njit(cache=True, nogil=True)
def _numbered(parent: np.ndarray, n: int) -> tuple[np.ndarray, int]:
    """Labels 1..n (union–find ``parent``) renumbered by part, 1..count: a root is its
    part's first label, so the parts are numbered in order of their first label."""
    final = np.zeros(n + 1, np.int32)
    count = 0
    for k in range(1, n + 1):
        root = _root(parent, k)
        if root == k:
            count += 1
            final[k] = count
        else:
            final[k] = final[root]
    return final, count


@njit(cache=True, nogil=True)
def border_reach(mask: np.ndarray) -> np.ndarray:
    """Cells of a 2-D ``mask`` joined to the array's border by a 4-connected path of mask
    cells: a flood fill from the border's mask cells, which visits only what it reaches
    (labelling the mask's parts and keeping those on the border takes a pass over all of
    them, and more)."""
    rows, cols = mask.shape
    reached = np.zeros((rows, cols), np.bool_)
    stack = np.empty(rows * cols, np.int64)
    top = 0
    for i in range(rows):
        for j in range(cols):
            on_border = i == 0 or j == 0 or i == rows - 1 or j == cols - 1
            if on_border and mask[i, j]:
                reached[i, j] = True
                stack[top] = i * cols + j
                top += 1
    while top > 0:
        top -= 1
        i, j = divmod(stack[top], cols)
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            a, b = i + di, j + dj
            if 0 <= a < rows and 0 <= b < cols and mask[a, b] and not reached[a, b]:
                reached[a, b] = True
                stack[top] = a * cols + b
                top += 1
    return reached
