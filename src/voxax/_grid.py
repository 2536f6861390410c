"""The regular grid that voxelizations are computed on."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from ._constants import MAX_CELL_VOLUME, MIN_CELL_VOLUME

__all__ = ["Grid", "SlabGrid"]


def _as_float_tuple(x, name: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in np.asarray(x, dtype=np.float64).reshape(-1))
    except (TypeError, ValueError) as err:
        raise TypeError(f"voxax.Grid: `{name}` must be a sequence of numbers, got {x!r}") from err
    return values


@dataclasses.dataclass(frozen=True)
class Grid:
    """An axis-aligned regular grid of `shape` cells spanning the box `[lower, upper]`.

    Cell `(i, j, k)` spans `lower + (i, j, k) * spacing` to `lower + (i+1, j+1, k+1) * spacing`
    and its centre is `lower + (i + .5, j + .5, k + .5) * spacing`. Arrays on the grid use
    `W[i, j, k]` indexing (x, then y, then z; z is the fastest, contiguous axis). In 2D the
    grid has two axes, x then y.

    A `Grid` is frozen and hashable: pass it as a static argument under `jax.jit`.

    **Arguments:**

    - `lower`: `(d,)` float, the corner with the smallest coordinates.
    - `upper`: `(d,)` float, the opposite corner; `upper > lower` on every axis.
    - `shape`: `(d,)` int, the number of cells per axis (any positive count, odd or even).

    **Example:**

    ```python
    >>> import voxax
    >>> g = voxax.Grid(lower=(0, 0, 0), upper=(1, 2, 3), shape=(4, 5, 6))
    >>> g.spacing
    (0.25, 0.4, 0.5)
    >>> g.voxel_volume
    0.05
    ```
    """

    lower: tuple[float, ...]
    upper: tuple[float, ...]
    shape: tuple[int, ...]

    def __post_init__(self):
        lower = _as_float_tuple(self.lower, "lower")
        upper = _as_float_tuple(self.upper, "upper")
        try:
            shape = tuple(int(operator_index(s)) for s in np.asarray(self.shape).reshape(-1))
        except (TypeError, ValueError):  # ValueError: a ragged sequence such as ([1], 2, 2)
            raise TypeError(f"voxax.Grid: `shape` must be a sequence of integers, got {self.shape!r}") from None
        d = len(shape)
        if d not in (2, 3):
            raise ValueError(f"voxax.Grid: only 2D and 3D grids are supported, got shape {shape}")
        if len(lower) != d or len(upper) != d:
            raise ValueError(
                f"voxax.Grid: `lower`, `upper` and `shape` must have the same length, "
                f"got {len(lower)}, {len(upper)} and {d}"
            )
        if any(s < 1 for s in shape):
            raise ValueError(f"voxax.Grid: every entry of `shape` must be >= 1, got {shape}")
        if not all(math.isfinite(v) for v in lower + upper):
            raise ValueError(f"voxax.Grid: corners must be finite, got lower={lower}, upper={upper}")
        if any(u <= lo for lo, u in zip(lower, upper)):
            raise ValueError(f"voxax.Grid: need upper > lower on every axis, got lower={lower}, upper={upper}")
        if any(not math.isfinite((u - lo) / n) or (u - lo) / n <= 0 for lo, u, n in zip(lower, upper, shape)):
            raise ValueError("voxax.Grid: the cell size underflows or overflows on some axis")
        volume = math.prod((u - lo) / n for lo, u, n in zip(lower, upper, shape))
        if not (MIN_CELL_VOLUME <= volume <= MAX_CELL_VOLUME):
            raise ValueError(
                f"voxax.Grid: the cell volume {volume:.3g} is outside [{MIN_CELL_VOLUME:g}, {MAX_CELL_VOLUME:g}]; rescale the problem "
                "(the kernels divide by the cell volume in double precision)"
            )
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)
        object.__setattr__(self, "shape", shape)

    # -- constructors -------------------------------------------------------------------

    @classmethod
    def cube(cls, n: int | Sequence[int], dim: int = 3, half_width: float = 1.0) -> Grid:
        """The cube `[-half_width, half_width]^dim` split into `n` cells per axis.

        With the defaults this is the grid of the paper: `[-1, 1]^3`.

        **Arguments:**

        - `n`: int (or `(dim,)` ints), the number of cells per axis.
        - `dim`: 2 or 3.
        - `half_width`: float, half the side length of the cube.

        **Example:**

        ```python
        >>> voxax.Grid.cube(64).shape
        (64, 64, 64)
        ```
        """
        from . import _validate

        where = "voxax.Grid.cube"
        if isinstance(n, (str, bytes)) or not (isinstance(n, (int, np.integer)) or hasattr(n, "__iter__")):
            raise TypeError(f"{where}: `n` must be an int or a sequence of ints, got {type(n).__name__}")
        if not isinstance(n, (int, np.integer)):
            n = tuple(_validate.positive_int(where, "n", s) for s in n)
        shape = _broadcast_shape(n, dim)
        h = _validate.positive_float(where, "half_width", half_width)
        return cls(lower=(-h,) * dim, upper=(h,) * dim, shape=shape)

    @classmethod
    def around(cls, vertices, n: int | Sequence[int] = 64, pad: float = 0.05, cubic_cells: bool = True) -> Grid:
        """A grid that encloses `vertices` with a margin.

        The bounding box of the vertices is enlarged by `pad` times its largest side on
        every side. With `cubic_cells=True` (the default) all cells are cubes: `n` is the
        number of cells along the longest axis and the other axes get as many cells as
        needed to cover the box (the box grows symmetrically to a whole number of cells).

        **Arguments:**

        - `vertices`: `(..., V, d)` float, the points to enclose (batch axes allowed), or a
          mesh object (`voxax.Mesh`, `trimesh.Trimesh`) whose vertices to enclose: those
          that some face uses (unused vertices do not widen the grid).
        - `n`: int or `(d,)` ints, cells along the longest axis (or per axis when
          `cubic_cells=False`).
        - `pad`: float >= 0, the margin as a fraction of the longest side.
        - `cubic_cells`: bool, whether to make every cell a cube.

        **Example:**

        ```python
        >>> mesh = voxax.data.icosphere(2)
        >>> g = voxax.Grid.around(mesh, 32)
        >>> max(g.shape)
        32
        ```
        """
        if hasattr(vertices, "vertices") and hasattr(vertices, "faces") and not hasattr(vertices, "shape"):
            v = np.asarray(vertices.vertices, dtype=np.float64)  # a mesh object: the vertices its faces use
            faces = np.asarray(vertices.faces)
            vertices = v[np.unique(faces)] if faces.size and v.ndim == 2 else v
        v = np.asarray(vertices, dtype=np.float64)
        if v.ndim < 2 or v.shape[-1] not in (2, 3) or v.shape[-2] == 0:
            raise ValueError(f"voxax.Grid.around: expected vertices of shape (..., V, 2|3) with V > 0, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError("voxax.Grid.around: vertices contain NaN or Inf")
        if pad < 0:
            raise ValueError(f"voxax.Grid.around: pad must be >= 0, got {pad}")
        d = v.shape[-1]
        pts = v.reshape(-1, d)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        extent = float(np.max(hi - lo))
        if extent == 0.0:
            extent = 1.0
        margin = pad * extent
        lo, hi = lo - margin, hi + margin
        if cubic_cells:
            if not isinstance(n, (int, np.integer)):
                raise TypeError("voxax.Grid.around: with cubic_cells=True, `n` must be a single int")
            h = (extent + 2 * margin) / int(n)
            counts = np.maximum(1, np.ceil((hi - lo) / h - 1e-9)).astype(int)
            centre = 0.5 * (lo + hi)
            lo = centre - 0.5 * counts * h
            hi = centre + 0.5 * counts * h
            shape = tuple(int(c) for c in counts)
        else:
            shape = _broadcast_shape(n, d)
            flat = hi - lo == 0
            lo = np.where(flat, lo - 0.5, lo)
            hi = np.where(flat, hi + 0.5, hi)
        return cls(lower=tuple(lo), upper=tuple(hi), shape=shape)

    # -- derived quantities -------------------------------------------------------------

    @property
    def dim(self) -> int:
        """The number of axes (2 or 3)."""
        return len(self.shape)

    @property
    def spacing(self) -> tuple[float, ...]:
        """The cell size per axis, `(upper - lower) / shape`."""
        return tuple((u - lo) / n for lo, u, n in zip(self.lower, self.upper, self.shape))

    @property
    def voxel_volume(self) -> float:
        """The volume (area in 2D) of one cell."""
        return float(np.prod(self.spacing))

    @property
    def size(self) -> int:
        """The number of cells."""
        return int(np.prod(self.shape))

    def edges(self, axis: int) -> np.ndarray:
        """The `shape[axis] + 1` plane coordinates along `axis`, as float64.

        Plane `i` sits at `lower + i * spacing` (the last one is exactly `upper`).
        """
        n = self.shape[axis]
        e = self.lower[axis] + np.arange(n + 1, dtype=np.float64) * self.spacing[axis]
        e[-1] = self.upper[axis]
        return e

    def slab(self, start: int, stop: int) -> SlabGrid:
        """The cells `[start, stop)` along x as a grid of their own.

        Its planes along x are this grid's planes (`self.edges(0)[start:stop + 1]`) bit for
        bit, also inside the kernels, so voxelizing on the slabs of a grid gives exactly the
        values of the whole grid there (the sharded voxelization relies on it).

        **Example:**

        ```python
        >>> g = voxax.Grid.cube(8)
        >>> s = g.slab(2, 5)
        >>> s.shape, bool((s.edges(0) == g.edges(0)[2:6]).all())
        ((3, 8, 8), True)
        ```
        """
        n = self.shape[0]
        if isinstance(self, SlabGrid):
            (x0, x1, nx), first = self.frame
        else:
            (x0, x1, nx), first = (self.lower[0], self.upper[0], n), 0
        start, stop = operator_index(start), operator_index(stop)
        if not 0 <= start < stop <= n:
            raise ValueError(f"voxax.Grid.slab: need 0 <= start < stop <= {n}, got start={start}, stop={stop}")
        edges = self.edges(0)
        return SlabGrid(
            lower=(float(edges[start]),) + tuple(self.lower[1:]),
            upper=(float(edges[stop]),) + tuple(self.upper[1:]),
            shape=(stop - start,) + tuple(self.shape[1:]),
            frame=((x0, x1, nx), first + start),
        )

    def centers(self, dtype=np.float64) -> np.ndarray:
        """The cell centres, an array of shape `(*shape, d)` in `W[i, j, k]` order.

        **Example:**

        ```python
        >>> voxax.Grid.cube(2, dim=2).centers()[1, 0]
        array([ 0.5, -0.5])
        ```
        """
        from . import _validate

        dtype = np.dtype(dtype)
        # the meshgrid's float64 axes and the stacked result (before the cast)
        _validate.check_allocation("voxax.Grid.centers", self.size * self.dim * (16 + dtype.itemsize),
                                   f"the array of cell centres of a {self.shape} grid")
        axes = [
            self.lower[a] + (np.arange(self.shape[a], dtype=np.float64) + 0.5) * self.spacing[a]
            for a in range(self.dim)
        ]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).astype(dtype)

    def nbytes(self, dtype=np.float32) -> int:
        """Bytes of one array of this grid's shape with the given dtype."""
        return self.size * np.dtype(dtype).itemsize

    def __repr__(self) -> str:
        return f"Grid(lower={self.lower}, upper={self.upper}, shape={self.shape})"


def operator_index(x) -> int:
    import operator

    if isinstance(x, (float, np.floating)):
        raise TypeError("not an integer")
    return operator.index(x)


def _broadcast_shape(n, dim: int) -> tuple[int, ...]:
    if dim not in (2, 3):
        raise ValueError(f"voxax.Grid: dim must be 2 or 3, got {dim}")
    if isinstance(n, (int, np.integer)):
        return (int(n),) * dim
    shape = tuple(int(operator_index(s)) for s in n)
    if len(shape) != dim:
        raise ValueError(f"voxax.Grid: expected {dim} cell counts, got {shape}")
    return shape


@dataclasses.dataclass(frozen=True)
class SlabGrid(Grid):
    """Cells `[first, first + shape[0])` along x of a frame grid, made by
    [`Grid.slab`][voxax.Grid.slab]: a grid whose x planes are the frame's.

    - `frame`: `((x0, x1, nx), first)`, the frame's extent and cell count along x, and the
      slab's first cell in it.
    """

    frame: tuple = ((0.0, 1.0, 1), 0)

    def __post_init__(self):
        super().__post_init__()
        (x0, x1, nx), first = self.frame
        frame = ((float(x0), float(x1), operator_index(nx)), operator_index(first))
        if not (0 <= frame[1] and frame[1] + self.shape[0] <= frame[0][2]):
            raise ValueError(f"SlabGrid: the slab does not fit its frame {frame}")
        object.__setattr__(self, "frame", frame)

    @property
    def spacing(self) -> tuple[float, ...]:
        (x0, x1, nx), _ = self.frame
        return ((x1 - x0) / nx,) + tuple((u - lo) / n for lo, u, n in zip(self.lower[1:], self.upper[1:], self.shape[1:]))

    def edges(self, axis: int) -> np.ndarray:
        if axis != 0:
            return super().edges(axis)
        (x0, x1, nx), first = self.frame
        k = first + np.arange(self.shape[0] + 1, dtype=np.float64)
        e = x0 + k * ((x1 - x0) / nx)
        if first + self.shape[0] == nx:
            e[-1] = x1
        return e

    def __repr__(self) -> str:
        (x0, x1, nx), first = self.frame
        return (f"SlabGrid(lower={self.lower}, upper={self.upper}, shape={self.shape}, "
                f"cells {first}:{first + self.shape[0]} of {nx} along x in [{x0}, {x1}])")
