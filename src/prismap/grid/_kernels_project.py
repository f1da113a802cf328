"""numba kernels of projective integration: voxels of a key box projected into the image, frustum bounds.

Called only by the grid's wrappers, which check and convert first. :func:`project_part` only finds the cells
(the integrator registers them in the frame accumulator in the walk's order, ``_kernels_accumulate.scatter_keys``).
Every kernel releases the GIL.
"""

import numba
import numpy as np

from prismap.grid._kernels_traverse import write_cell


@numba.njit(cache=True, nogil=True, inline="always")
def _line_cells(line, walk, projection):
    """The kept voxels of line ``line`` of the key box (``i0 * n1 + i1``: the voxels along the walk's line
    axis, :func:`_walk_setup`), written to the walk's line scratch in order along the line; returns how many.

    Each voxel centre is projected into the (subsampled) image; the nearest grid pixel with a valid
    ray (``ray_index >= 0``) is the voxel's ray. The interval is the slab intersection of that ray with
    the voxel's box; if the ray misses the box (it passes up to half a pixel beside the centre), the
    interval is the centre's depth +- half a voxel. The voxel is kept by the rule of ``cast_rays``.
    The line is first narrowed to the part that may project into the image (:func:`_line_in_image`),
    then runs of :data:`SPAN` voxels that lie wholly beyond the farthest stop depth of the image tiles they
    project to are skipped without visiting each voxel (:func:`_run_beyond_stops`): on a street most of
    the frustum's key box lies behind the first surfaces. A visited voxel reads its pixel's stop depth
    (``stops``, -inf = no ray) before anything of its ray.

    Parameters
    ----------
    line : int
        The line, ``i0 * n1 + i1``.
    walk : tuple
        The walk's state and line scratch (:func:`_walk_setup`); the scratch is written.
    projection : Projection
        The frame (:class:`~prismap.grid._kernel_args.Projection`).
    """
    (
        key_min,
        shape,
        origin,
        R_cam_world,
        focal,
        _,
        _,
        subsample,
        ray_index,
        rays,
        exclusive,
        stops,
        tile_stop,
        voxel_size,
    ) = projection
    a0, a1, a2, step, k, w, col_offset, row_offset, scale_px, line_keys, line_ray, line_t0, line_t1 = walk
    n1 = shape[a1]
    k[a0] = key_min[a0] + line // n1
    k[a1] = key_min[a1] + line % n1
    for a in (a0, a1):
        w[a] = (k[a] + 0.5) * voxel_size - origin[a]
    rows, cols = ray_index.shape
    half = 0.5 * voxel_size
    reach = np.sqrt(0.75) * voxel_size  # centre to corner: no point of the voxel is nearer in depth
    w[a2] = (key_min[a2] + 0.5) * voxel_size - origin[a2]
    px0 = R_cam_world[0, 0] * w[0] + R_cam_world[0, 1] * w[1] + R_cam_world[0, 2] * w[2]
    py0 = R_cam_world[1, 0] * w[0] + R_cam_world[1, 1] * w[1] + R_cam_world[1, 2] * w[2]
    pz0 = R_cam_world[2, 0] * w[0] + R_cam_world[2, 1] * w[1] + R_cam_world[2, 2] * w[2]
    lo, hi = _line_in_image(px0, py0, pz0, step, shape[a2], scale_px, col_offset, row_offset, cols, rows)
    c = 0
    for base in range(lo, hi, SPAN):
        top = min(base + SPAN, hi)
        last = top - 1
        if _run_beyond_stops(
            px0 + base * step[0],
            py0 + base * step[1],
            pz0 + base * step[2],
            px0 + last * step[0],
            py0 + last * step[1],
            pz0 + last * step[2],
            scale_px,
            col_offset,
            row_offset,
            reach,
            tile_stop,
        ):
            continue
        for i2 in range(base, top):
            k[a2] = key_min[a2] + i2
            w[a2] = (k[a2] + 0.5) * voxel_size - origin[a2]
            wx, wy, wz = w[0], w[1], w[2]
            pz = R_cam_world[2, 0] * wx + R_cam_world[2, 1] * wy + R_cam_world[2, 2] * wz
            if pz <= 0.0:
                continue
            px = R_cam_world[0, 0] * wx + R_cam_world[0, 1] * wy + R_cam_world[0, 2] * wz
            py = R_cam_world[1, 0] * wx + R_cam_world[1, 1] * wy + R_cam_world[1, 2] * wz
            scale = focal / (pz * subsample)
            col = np.floor(px * scale + col_offset)
            row = np.floor(py * scale + row_offset)
            if col < 0 or row < 0 or col >= cols or row >= rows:
                continue
            pixel_row, pixel_col = np.int64(row), np.int64(col)
            stop = stops[pixel_row, pixel_col]
            if pz - reach > stop:  # the whole voxel lies beyond the ray's stop depth (or there is no ray)
                continue
            ray = ray_index[pixel_row, pixel_col]
            # Slab intersection of the ray with the voxel box, in depth units.
            t0, t1 = _slab(
                rays[ray, 0],
                rays[ray, 1],
                rays[ray, 2],
                k[0] * voxel_size - origin[0],
                k[1] * voxel_size - origin[1],
                k[2] * voxel_size - origin[2],
                voxel_size,
            )
            t0 = max(t0, 0.0)
            if t1 <= t0:
                t0 = max(pz - half, 0.0)
                t1 = pz + half
            if exclusive[ray]:
                if t1 > stop:
                    continue
            elif t0 > stop:
                continue
            line_ray[c] = ray
            c = write_cell(line_keys, line_t0, line_t1, c, k[0], k[1], k[2], t0, t1)
    return c


@numba.njit(cache=True, nogil=True, inline="always")
def _walk_setup(projection):
    """State of a walk over the key box of ``projection`` (:class:`~prismap.grid._kernel_args.Projection`): its
    loop axes (:func:`_loop_axes`), the camera-frame step of one voxel along the line axis, the key and centre
    (relative to the origin) of the current voxel, the image offsets and scale, and scratch for one line: keys
    (n2, 3) int32, ray (n2,) int64, t_in, t_out (n2,) float64. Returns it and the number of lines."""
    R_cam_world, shape, voxel_size, subsample = (
        projection.R_cam_world,
        projection.shape,
        projection.voxel_size,
        projection.subsample,
    )
    a0, a1, a2 = _loop_axes(R_cam_world)
    step = np.empty(3)
    for r in range(3):
        step[r] = R_cam_world[r, a2] * voxel_size
    n2 = shape[a2]
    walk = (
        a0,
        a1,
        a2,
        step,
        np.empty(3, dtype=np.int64),
        np.empty(3),
        projection.cx / subsample + 0.5,
        projection.cy / subsample + 0.5,
        projection.focal / subsample,
        np.empty((n2, 3), dtype=np.int32),
        np.empty(n2, dtype=np.int64),
        np.empty(n2),
        np.empty(n2),
    )
    return walk, shape[a0] * shape[a1]


@numba.njit(cache=True, nogil=True)
def project_part(projection, start, stop, capacity, max_cells):
    """Voxels of a key box seen by a pixel ray (:func:`_line_cells`) on lines ``start`` to ``stop - 1``, in the
    walk's order; the accumulator is not touched, so parts of the lines may be walked in several threads.

    The box is walked in lines along the world axis nearest the image's rows (:func:`_loop_axes`), so that
    consecutive voxels read neighbouring pixels; lines are numbered ``i0 * n1 + i1`` (outer, middle axis).
    Returns ``keys (M, 3) int32, ray_of_cell (M,) int64, t_in, t_out (M,) float64`` and the cell count ``m``:
    the arrays start with room for ``capacity`` cells and grow by half when full, up to ``max_cells``; beyond
    it voxels are only counted (``m`` exceeds the arrays' length; the caller refuses the frame).
    :func:`walk_lines` gives the number of lines.

    Parameters
    ----------
    projection : Projection
        The frame (:class:`~prismap.grid._kernel_args.Projection`).
    start, stop : int
        The lines of this part.
    capacity : int, cells
        Room the cell arrays start with.
    max_cells : int, cells
        Most cells the arrays may hold.
    """
    walk, _ = _walk_setup(projection)
    line_keys, line_ray, line_t0, line_t1 = walk[9], walk[10], walk[11], walk[12]
    size = max(min(capacity, max_cells), 16)
    keys, ray_of_cell = np.empty((size, 3), dtype=np.int32), np.empty(size, dtype=np.int64)
    t_in, t_out = np.empty(size), np.empty(size)
    m = 0
    for line in range(start, stop):
        c = _line_cells(line, walk, projection)
        if c == 0:
            continue
        if m + c > ray_of_cell.size:
            if m + c > max_cells:  # over the bound: only count
                m += c
                continue
            keys, ray_of_cell, t_in, t_out = _grown(
                keys, ray_of_cell, t_in, t_out, m, min(max(m + m // 2, m + c), max_cells)
            )
        keys[m : m + c] = line_keys[:c]
        ray_of_cell[m : m + c] = line_ray[:c]
        t_in[m : m + c] = line_t0[:c]
        t_out[m : m + c] = line_t1[:c]
        m += c
    return keys, ray_of_cell, t_in, t_out, m


SPAN = 8
"""Voxels of a line that :func:`_line_cells` tests as one run against the tiles' stop depths."""

TILE = 8
"""Side (subsampled pixels) of the image tiles whose farthest stop depth bounds a run of voxels."""


@numba.njit(cache=True, nogil=True)
def _grown(keys, ray_of_cell, t_in, t_out, m, size):
    """The cell arrays with room for ``size`` cells, their first ``m`` rows kept."""
    grown = (np.empty((size, 3), dtype=np.int32), np.empty(size, dtype=np.int64), np.empty(size), np.empty(size))
    grown[0][:m] = keys[:m]
    grown[1][:m] = ray_of_cell[:m]
    grown[2][:m] = t_in[:m]
    grown[3][:m] = t_out[:m]
    return grown


@numba.njit(cache=True, nogil=True)
def walk_lines(R_cam_world, shape):
    """Number of lines of the walk of :func:`project_part` over a key box of ``shape`` (3,)."""
    a0, a1, _ = _loop_axes(R_cam_world)
    return shape[a0] * shape[a1]


@numba.njit(cache=True, nogil=True)
def _loop_axes(R_cam_world):
    """World axes ``(outer, middle, inner)`` of the walk of :func:`project_part`: the inner one nearest the camera's
    x (image rows), the middle one nearest its y among the others, the outer one the last."""
    inner = 0
    for a in range(1, 3):
        if abs(R_cam_world[0, a]) > abs(R_cam_world[0, inner]):
            inner = a
    middle, other = (inner + 1) % 3, (inner + 2) % 3
    if abs(R_cam_world[1, other]) > abs(R_cam_world[1, middle]):
        middle = other
    return 3 - inner - middle, middle, inner


@numba.njit(cache=True, nogil=True)
def stop_image(ray_index, t_stop):
    """(rows, cols) float64: the stop depth of each pixel's ray, -inf where there is none."""
    rows, cols = ray_index.shape
    out = np.empty((rows, cols))
    for r in range(rows):
        for c in range(cols):
            ray = ray_index[r, c]
            out[r, c] = t_stop[ray] if ray >= 0 else -np.inf
    return out


@numba.njit(cache=True, nogil=True)
def tile_stops(stops):
    """(rows / TILE, cols / TILE) float64: the largest stop depth of each tile of the stop image."""
    rows, cols = stops.shape
    out = np.full(((rows + TILE - 1) // TILE, (cols + TILE - 1) // TILE), -np.inf)
    for r in range(rows):
        for c in range(cols):
            out[r // TILE, c // TILE] = max(out[r // TILE, c // TILE], stops[r, c])
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _run_beyond_stops(px, py, pz, qx, qy, qz, scale, col_offset, row_offset, reach, tile_stop):
    """Whether every voxel centre on the segment from ``p`` to ``q`` (camera frame, relative to the origin) is
    in front of the camera and nearer than ``reach`` to none of the stop depths of the tiles it projects into.

    The segment projects onto the image segment between its ends' projections, so onto pixels within their
    bounding box (one pixel of margin for rounding); a voxel of the run is kept only if its depth minus
    ``reach`` is at most its ray's stop depth, at most the largest stop depth of those tiles.
    """
    if pz <= 0.0 or qz <= 0.0:
        return False
    col_p, col_q = px * scale / pz + col_offset, qx * scale / qz + col_offset
    row_p, row_q = py * scale / pz + row_offset, qy * scale / qz + row_offset
    n_rows, n_cols = tile_stop.shape
    c0, c1 = max(min(col_p, col_q), -2.0), min(max(col_p, col_q), n_cols * TILE + 1.0)  # ints below stay small
    r0, r1 = max(min(row_p, row_q), -2.0), min(max(row_p, row_q), n_rows * TILE + 1.0)
    tc0 = max(np.int64(np.floor(c0)) - 1, 0) // TILE
    tc1 = min(np.int64(np.floor(c1)) + 1, n_cols * TILE - 1) // TILE
    tr0 = max(np.int64(np.floor(r0)) - 1, 0) // TILE
    tr1 = min(np.int64(np.floor(r1)) + 1, n_rows * TILE - 1) // TILE
    farthest = -np.inf
    for tr in range(tr0, tr1 + 1):
        for tc in range(tc0, tc1 + 1):
            farthest = max(farthest, tile_stop[tr, tc])
    return min(pz, qz) - reach > farthest


@numba.njit(cache=True, nogil=True, inline="always")
def _half_line(slope, value, lo, hi):
    """Narrow ``[lo, hi)`` (indices ``i``) to where ``value + i slope >= 0`` may hold, one index of margin.

    The margin absorbs rounding: the caller still tests each index exactly, so this only skips
    indices that surely fail. A zero slope leaves the range alone (the exact test decides).
    """
    if slope > 0.0:
        bound = -value / slope
        if bound > lo:
            lo = max(lo, np.int64(np.floor(min(bound, hi + 1.0))) - 1)
    elif slope < 0.0:
        bound = -value / slope
        if bound < hi:
            hi = min(hi, np.int64(np.ceil(max(bound, lo - 1.0))) + 2)
    return lo, hi


@numba.njit(cache=True, nogil=True, inline="always")
def _line_in_image(px, py, pz, step, n, scale, col_offset, row_offset, cols, rows):
    """Index range ``[lo, hi)`` of the voxels ``i`` of one line of the box (centres ``p + i step``, camera
    frame, relative to the origin) that may be in front of the camera and project into the image, a
    superset of those that do.

    Each condition is linear in ``i`` once multiplied by the (positive) depth: ``pz > 0``,
    ``px scale + col_offset pz >= 0``, ``px scale + (col_offset - cols) pz < 0`` and the same for rows.
    """
    dx, dy, dz = step[0], step[1], step[2]
    lo, hi = np.int64(0), np.int64(n)
    lo, hi = _half_line(dz, pz, lo, hi)
    lo, hi = _half_line(dx * scale + col_offset * dz, px * scale + col_offset * pz, lo, hi)
    lo, hi = _half_line(-(dx * scale + (col_offset - cols) * dz), -(px * scale + (col_offset - cols) * pz), lo, hi)
    lo, hi = _half_line(dy * scale + row_offset * dz, py * scale + row_offset * pz, lo, hi)
    lo, hi = _half_line(-(dy * scale + (row_offset - rows) * dz), -(py * scale + (row_offset - rows) * pz), lo, hi)
    return lo, max(lo, hi)


@numba.njit(cache=True, nogil=True, inline="always")
def _slab_axis(r, lo, size, t0, t1):
    """Clip the depth interval ``[t0, t1]`` to where ``lo <= t r < lo + size`` on one axis."""
    if r != 0.0:
        inv = 1.0 / r
        ta = lo * inv
        tb = (lo + size) * inv
        return max(t0, min(ta, tb)), min(t1, max(ta, tb))
    if lo > 0.0 or lo + size <= 0.0:
        return t0, -np.inf
    return t0, t1


@numba.njit(cache=True, nogil=True, inline="always")
def _slab(rx, ry, rz, lx, ly, lz, size):
    """Depth interval of the ray ``t (rx, ry, rz)`` inside the box ``[l, l + size)`` (empty: t1 <= t0)."""
    t0, t1 = _slab_axis(rx, lx, size, -np.inf, np.inf)
    t0, t1 = _slab_axis(ry, ly, size, t0, t1)
    return _slab_axis(rz, lz, size, t0, t1)


@numba.njit(cache=True, nogil=True)
def frustum_box(origin, rays, t_stop, voxel_size):
    """Key box of the origin and every ray's stop point, one voxel of margin: ``(key_min (3,), shape (3,))``
    int64 and the number of rays that cast anything (``t_stop > 0``)."""
    lo = np.floor(origin / voxel_size)
    hi = lo.copy()
    n = 0
    for i in range(rays.shape[0]):
        if t_stop[i] > 0.0:
            n += 1
            for ax in range(3):
                k = np.floor((origin[ax] + rays[i, ax] * t_stop[i]) / voxel_size)
                lo[ax] = min(lo[ax], k)
                hi[ax] = max(hi[ax], k)
    key_min = lo.astype(np.int64) - 1
    return key_min, hi.astype(np.int64) + 2 - key_min, n


@numba.njit(cache=True, nogil=True)
def group_by_ray(ray_of_cell, n_rays, t_in, t_out, ray_key):
    """Cells grouped by ray, the rays in the order of their key and, within a key, of their first cell, and each
    ray's cells in their order (counting sorts over the rays that have cells and over the keys: nothing of it but
    one fill costs per ray of the frame).

    ``ray_key`` (n_rays,) int64 ``>= 0``: each ray's key (its error class + 1, so that a conditioned model's rays
    of one class, and their cells, come contiguous; all 0 for one order by first cell).
    Returns ``order`` (C,) int64 (grouped cell ``j`` is cell ``order[j]``), the grouped ``t_in, t_out`` (C,),
    the rays that have cells ``used (U,)`` int64, and per grouped cell the index of its ray in ``used`` (C,).
    """
    n = ray_of_cell.size
    slot = np.full(n_rays, -1, dtype=np.int32)
    seen = np.empty(n, dtype=np.int64)
    first_local = np.empty(n, dtype=np.int64)
    u = 0
    for i in range(n):
        r = ray_of_cell[i]
        if slot[r] < 0:
            slot[r] = u
            seen[u] = r
            u += 1
        first_local[i] = slot[r]
    n_keys = 1
    for k in range(u):
        n_keys = max(n_keys, ray_key[seen[k]] + 1)
    key_start = np.zeros(n_keys + 1, dtype=np.int64)
    for k in range(u):
        key_start[ray_key[seen[k]] + 1] += 1
    for key in range(n_keys):
        key_start[key + 1] += key_start[key]
    used = np.empty(u, dtype=np.int64)
    rank = np.empty(u, dtype=np.int64)  # each first-seen ray's place in key order
    for k in range(u):
        j = key_start[ray_key[seen[k]]]
        key_start[ray_key[seen[k]]] = j + 1
        rank[k] = j
        used[j] = seen[k]
    for i in range(n):
        first_local[i] = rank[first_local[i]]
    counts = np.zeros(u + 1, dtype=np.int64)
    for i in range(n):
        counts[first_local[i] + 1] += 1
    for k in range(u):
        counts[k + 1] += counts[k]
    order = np.empty(n, dtype=np.int64)
    local = np.empty(n, dtype=np.int64)
    grouped_in = np.empty(n)
    grouped_out = np.empty(n)
    for i in range(n):
        k = first_local[i]
        j = counts[k]
        counts[k] = j + 1
        order[j] = i
        local[j] = k
        grouped_in[j] = t_in[i]
        grouped_out[j] = t_out[i]
    return order, grouped_in, grouped_out, used, local
