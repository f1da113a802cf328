"""numba kernels of projective integration: voxels of a key box projected into the image, frustum bounds.

Called only by the grid's wrappers, which check and convert first. Every kernel releases the GIL.
"""

import numba
import numpy as np

from prismap.grid._kernels_traverse import write_cell


@numba.njit(cache=True, nogil=True)
def project_voxels(key_min, shape, origin, R_cam_world, focal, cx, cy, subsample, ray_index, rays, t_stop, exclusive,
                   voxel_size, capacity):
    """Voxels of a key box seen by a pixel ray, with the voxel's depth interval on that ray.

    Each voxel centre is projected into the (subsampled) image; the nearest grid pixel with a valid
    ray (``ray_index >= 0``) is the voxel's ray. The interval is the slab intersection of that ray with
    the voxel's box; if the ray misses the box (it passes up to half a pixel beside the centre), the
    interval is the centre's depth +- half a voxel. The voxel is kept by the same rule as
    :func:`cast_rays`. Returns ``ray_of_cell, keys, t_in, t_out`` as :func:`cast_rays` does, in the
    order of the box (x, then y, then z), and how many voxels are kept: when that exceeds ``capacity``
    (the outputs' size) only the first ``capacity`` are returned; call again with room for all.

    Runs of :data:`SPAN` voxels of a key column that lie wholly beyond the farthest stop depth of the image
    tiles (:data:`TILE` pixels square) their centres project to are skipped without visiting each voxel:
    on a street most of the frustum's key box lies behind the first surfaces.
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    ray_of_cell = np.empty(capacity, dtype=np.int64)
    keys = np.empty((capacity, 3), dtype=np.int32)
    t_in_out = np.empty(capacity, dtype=np.float64)
    t_out_out = np.empty(capacity, dtype=np.float64)
    rows, cols = ray_index.shape
    half = 0.5 * voxel_size
    reach = np.sqrt(0.75) * voxel_size  # centre to corner: no point of the voxel is nearer in depth
    col_offset = cx / subsample + 0.5
    row_offset = cy / subsample + 0.5
    scale_px = focal / subsample
    tile_stop = _tile_stops(ray_index, t_stop)
    m = 0
    for ix in range(nx):
        kx = key_min[0] + ix
        wx = (kx + 0.5) * voxel_size - origin[0]
        for iy in range(ny):
            ky = key_min[1] + iy
            wy = (ky + 0.5) * voxel_size - origin[1]
            z_lo, z_hi = _column_in_image(R_cam_world, wx, wy, key_min[2], nz, origin[2], voxel_size, scale_px,
                                          col_offset, row_offset, cols, rows)
            for base in range(z_lo, z_hi, SPAN):
                top = min(base + SPAN, z_hi)
                wz0 = (key_min[2] + base + 0.5) * voxel_size - origin[2]
                if _run_beyond_stops(R_cam_world, wx, wy, wz0, wz0 + (top - 1 - base) * voxel_size, scale_px,
                                     col_offset, row_offset, reach, tile_stop):
                    continue
                for iz in range(base, top):
                    kz = key_min[2] + iz
                    wz = (kz + 0.5) * voxel_size - origin[2]
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
                    ray = ray_index[np.int64(row), np.int64(col)]
                    if ray < 0:
                        continue
                    stop = t_stop[ray]
                    if pz - reach > stop:  # the whole voxel lies beyond the ray's stop depth
                        continue
                    # Slab intersection of the ray with the voxel box, in depth units.
                    t0, t1 = _slab(rays[ray, 0], rays[ray, 1], rays[ray, 2], kx * voxel_size - origin[0],
                                   ky * voxel_size - origin[1], kz * voxel_size - origin[2], voxel_size)
                    t0 = max(t0, 0.0)
                    if t1 <= t0:
                        t0 = max(pz - half, 0.0)
                        t1 = pz + half
                    if exclusive[ray]:
                        if t1 > stop:
                            continue
                    elif t0 > stop:
                        continue
                    if m >= capacity:  # full: only count (the caller repeats with room for all)
                        m += 1
                        continue
                    ray_of_cell[m] = ray
                    m = write_cell(keys, t_in_out, t_out_out, m, kx, ky, kz, t0, t1)
    n = min(m, capacity)
    return ray_of_cell[:n], keys[:n], t_in_out[:n], t_out_out[:n], m


SPAN = 8
"""Voxels of a key column that :func:`project_voxels` tests as one run against the tiles' stop depths."""

TILE = 8
"""Side (subsampled pixels) of the image tiles whose farthest stop depth bounds a run of voxels."""


@numba.njit(cache=True, nogil=True)
def _tile_stops(ray_index, t_stop):
    """(rows / TILE, cols / TILE) float64: the largest stop depth of the rays of each tile, -inf for none."""
    rows, cols = ray_index.shape
    out = np.full(((rows + TILE - 1) // TILE, (cols + TILE - 1) // TILE), -np.inf)
    for r in range(rows):
        for c in range(cols):
            ray = ray_index[r, c]
            if ray >= 0:
                out[r // TILE, c // TILE] = max(out[r // TILE, c // TILE], t_stop[ray])
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _run_beyond_stops(R_cam_world, wx, wy, wz0, wz1, scale, col_offset, row_offset, reach, tile_stop):
    """Whether every voxel centre on the segment ``(wx, wy, wz0..wz1)`` (relative to the origin) is in front
    of the camera and nearer than ``reach`` to none of the stop depths of the tiles it projects into.

    The segment projects onto the image segment between its ends' projections, so onto pixels within their
    bounding box (one pixel of margin for rounding); a voxel of the run is kept only if its depth minus
    ``reach`` is at most its ray's stop depth, at most the largest stop depth of those tiles.
    """
    dx, dy, dz = R_cam_world[0, 2], R_cam_world[1, 2], R_cam_world[2, 2]
    px = R_cam_world[0, 0] * wx + R_cam_world[0, 1] * wy + dx * wz0
    py = R_cam_world[1, 0] * wx + R_cam_world[1, 1] * wy + dy * wz0
    pz = R_cam_world[2, 0] * wx + R_cam_world[2, 1] * wy + dz * wz0
    run = wz1 - wz0
    qx, qy, qz = px + dx * run, py + dy * run, pz + dz * run
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
def _column_in_image(R_cam_world, wx, wy, kz_min, nz, oz, voxel_size, scale, col_offset, row_offset, cols, rows):
    """Index range ``[lo, hi)`` of the voxels ``iz`` of one key column (centre ``(wx, wy, (kz_min + iz +
    0.5) voxel_size - oz)`` relative to the origin) that may be in front of the camera and project into
    the image, a superset of those that do.

    Each condition is linear in ``iz`` once multiplied by the (positive) depth ``pz``: ``pz > 0``,
    ``px scale + col_offset pz >= 0``, ``px scale + (col_offset - cols) pz < 0`` and the same for rows.
    """
    wz = (kz_min + 0.5) * voxel_size - oz
    px = R_cam_world[0, 0] * wx + R_cam_world[0, 1] * wy + R_cam_world[0, 2] * wz
    py = R_cam_world[1, 0] * wx + R_cam_world[1, 1] * wy + R_cam_world[1, 2] * wz
    pz = R_cam_world[2, 0] * wx + R_cam_world[2, 1] * wy + R_cam_world[2, 2] * wz
    dx, dy, dz = R_cam_world[0, 2] * voxel_size, R_cam_world[1, 2] * voxel_size, R_cam_world[2, 2] * voxel_size
    lo, hi = np.int64(0), np.int64(nz)
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
def rotate_rays(rays, rotation):
    """``rays @ rotation.T`` for (R, 3) rays: numpy's BLAS product of this shape costs ~10x more."""
    out = np.empty_like(rays)
    for i in range(rays.shape[0]):
        x, y, z = rays[i, 0], rays[i, 1], rays[i, 2]
        for a in range(3):
            out[i, a] = rotation[a, 0] * x + rotation[a, 1] * y + rotation[a, 2] * z
    return out


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
def sort_by_ray(ray_of_cell, n_rays, cell_index, t_in, t_out):
    """Cells grouped by ray, in their order within a ray (a counting sort).

    Returns the sorted ``cell_index, t_in, t_out`` (C,), the rays that have cells ``used (U,)``
    (increasing) and, per sorted cell, the index of its ray in ``used`` (C,).
    """
    counts = np.zeros(n_rays + 1, dtype=np.int64)
    for i in range(ray_of_cell.size):
        counts[ray_of_cell[i] + 1] += 1
    n_used = 0
    for r in range(n_rays):
        if counts[r + 1] > 0:
            n_used += 1
        counts[r + 1] += counts[r]
    used = np.empty(n_used, dtype=np.int64)
    local = np.empty(ray_of_cell.size, dtype=np.int64)
    u = 0
    for r in range(n_rays):
        if counts[r + 1] > counts[r]:
            used[u] = r
            local[counts[r] : counts[r + 1]] = u
            u += 1
    sorted_index = np.empty(cell_index.size, dtype=np.int64)
    sorted_in = np.empty(t_in.size)
    sorted_out = np.empty(t_out.size)
    for i in range(ray_of_cell.size):
        r = ray_of_cell[i]
        j = counts[r]
        counts[r] = j + 1
        sorted_index[j] = cell_index[i]
        sorted_in[j] = t_in[i]
        sorted_out[j] = t_out[i]
    return sorted_index, sorted_in, sorted_out, used, local
