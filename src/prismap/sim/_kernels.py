"""numba kernels of the simulator: ray casting against axis-aligned boxes, texturing, visibility.

Called only through the wrappers in ``_scene3d.py`` and ``_truth.py``, which check and convert the inputs.
``error_model="numpy"`` keeps float division by zero IEEE (inf), as numpy does.
"""

import numba
import numpy as np


@numba.njit(cache=True, error_model="numpy")
def _first_hit(origin, direction, box_lo, box_hi):
    """Nearest entry of the ray ``origin + t direction`` (t > 0) into any box (slab test).

    Returns ``(t, box, axis)``: ray parameter, box index and the axis of the entered face; ``(inf, -1, -1)``
    on a miss. Boxes containing the origin are ignored (a camera is never inside a solid).
    """
    best_t = np.inf
    best_box = -1
    best_axis = -1
    for b in range(box_lo.shape[0]):
        t_near = -np.inf
        t_far = np.inf
        axis_near = -1
        missed = False
        for a in range(3):
            d = direction[a]
            o = origin[a]
            if d == 0.0:
                if o < box_lo[b, a] or o > box_hi[b, a]:
                    missed = True
                    break
                continue
            t0 = (box_lo[b, a] - o) / d
            t1 = (box_hi[b, a] - o) / d
            if t0 > t1:
                t0, t1 = t1, t0
            if t0 > t_near:
                t_near = t0
                axis_near = a
            if t1 < t_far:
                t_far = t1
            if t_near > t_far or t_far <= 0.0 or t_near >= best_t:
                missed = True  # no entry, behind the origin, or farther than the best hit so far
                break
        if missed or t_near <= 0.0:
            continue
        if t_near < best_t:
            best_t = t_near
            best_box = b
            best_axis = axis_near
    return best_t, best_box, best_axis


@numba.njit(cache=True, error_model="numpy")
def _sample_bilinear(texture, row, col, out):
    """Bilinear sample of a tiled (wrapping) ``texture`` (S, S, 3) at fractional ``(row, col)`` into ``out``."""
    size_r = texture.shape[0]
    size_c = texture.shape[1]
    r = row - np.floor(row / size_r) * size_r
    c = col - np.floor(col / size_c) * size_c
    r0 = int(np.floor(r))
    c0 = int(np.floor(c))
    fr = r - r0
    fc = c - c0
    r0 %= size_r
    c0 %= size_c
    r1 = (r0 + 1) % size_r
    c1 = (c0 + 1) % size_c
    for k in range(3):
        top = texture[r0, c0, k] * (1.0 - fc) + texture[r0, c1, k] * fc
        bottom = texture[r1, c0, k] * (1.0 - fc) + texture[r1, c1, k] * fc
        out[k] = top * (1.0 - fr) + bottom * fr


@numba.njit(cache=True, error_model="numpy")
def _pixel_direction(rotation, focal, cx, cy, u, v, out):
    x = (u - cx) / focal
    y = (v - cy) / focal
    for a in range(3):
        out[a] = rotation[a, 0] * x + rotation[a, 1] * y + rotation[a, 2]


@numba.njit(cache=True, error_model="numpy")
def cast_view(origin, rotation, focal, cx, cy, height, width, box_lo, box_hi):
    """Ray-cast every pixel of a pinhole view against boxes.

    ``rotation`` is R_world_cam (3, 3); the ray of pixel (u, v) is ``rotation @ ((u-cx)/f, (v-cy)/f, 1)``, so
    its parameter at a hit is the camera depth z.

    Returns ``depth`` (H, W) float64 (metres of camera z, inf on a miss), ``box`` (H, W) int32 (index of the
    box hit, -1 on a miss) and ``axis`` (H, W) int8 (normal axis of the face hit).
    """
    depth = np.full((height, width), np.inf)
    box = np.full((height, width), -1, dtype=np.int32)
    axis = np.full((height, width), -1, dtype=np.int8)
    direction = np.empty(3)
    for v in range(height):
        for u in range(width):
            _pixel_direction(rotation, focal, cx, cy, u, v, direction)
            t, b, a = _first_hit(origin, direction, box_lo, box_hi)
            if b >= 0:
                depth[v, u] = t
                box[v, u] = b
                axis[v, u] = a
    return depth, box, axis


@numba.njit(cache=True, error_model="numpy")
def shade_view(origin, rotation, focal, cx, cy, depth, box, axis, box_texture, box_texel, box_tint, textures, shade):
    """Colour of every hit pixel of :func:`cast_view`'s output: bilinear texture x tint x face shading.

    A face with normal axis ``a`` is textured in the world coordinates of the other two axes (texel size
    ``box_texel`` metres), vertical faces with -z as the row (upright). ``shade`` (3, 2) scales the colour by
    face axis and side (0: the face at the box's ``lo``, 1: at ``hi``). Returns (H, W, 3) float32, 0 on a miss.
    """
    height, width = depth.shape
    image = np.zeros((height, width, 3), dtype=np.float32)
    direction = np.empty(3)
    colour = np.empty(3)
    for v in range(height):
        for u in range(width):
            b = box[v, u]
            if b < 0:
                continue
            a = axis[v, u]
            _pixel_direction(rotation, focal, cx, cy, u, v, direction)
            t = depth[v, u]
            px = origin[0] + t * direction[0]
            py = origin[1] + t * direction[1]
            pz = origin[2] + t * direction[2]
            if a == 2:
                row, col = py / box_texel[b], px / box_texel[b]
            elif a == 1:
                row, col = -pz / box_texel[b], px / box_texel[b]
            else:
                row, col = -pz / box_texel[b], py / box_texel[b]
            _sample_bilinear(textures[box_texture[b]], row, col, colour)
            side = 0 if direction[a] > 0 else 1
            for k in range(3):
                image[v, u, k] = colour[k] * box_tint[b, k] * shade[a, side]
    return image


@numba.njit(cache=True)
def mark_visible(mask, key_lo, voxel_size, planar_z, rotation_wc, position_w, focal, cx, cy, depth, max_depth):
    """Set ``mask[i, j, k]`` for voxels whose centre a camera sees in front of (or on) the surface.

    Voxel ``(i, j, k)`` has key ``key_lo + (i, j, k)`` and centre ``(key + 0.5) * voxel_size``; with
    ``planar_z`` finite the centre's z is replaced by it (2-D worlds: the sensor plane). ``rotation_wc`` (3, 3)
    and ``position_w`` (3,) are the camera's pose (R_world_cam, camera centre). A centre counts if it
    projects (nearest pixel) into the image, its camera depth is positive, not beyond ``max_depth`` and not
    beyond the true surface depth ``depth`` (H, W) at that pixel (inf where nothing is hit).
    """
    height, width = depth.shape
    offset = np.empty(3)
    for i in range(mask.shape[0]):
        offset[0] = (key_lo[0] + i + 0.5) * voxel_size - position_w[0]
        for j in range(mask.shape[1]):
            offset[1] = (key_lo[1] + j + 0.5) * voxel_size - position_w[1]
            for k in range(mask.shape[2]):
                centre_z = planar_z if np.isfinite(planar_z) else (key_lo[2] + k + 0.5) * voxel_size
                offset[2] = centre_z - position_w[2]
                z = rotation_wc[0, 2] * offset[0] + rotation_wc[1, 2] * offset[1] + rotation_wc[2, 2] * offset[2]
                if z <= 0.0 or z > max_depth:
                    continue
                x = rotation_wc[0, 0] * offset[0] + rotation_wc[1, 0] * offset[1] + rotation_wc[2, 0] * offset[2]
                y = rotation_wc[0, 1] * offset[0] + rotation_wc[1, 1] * offset[1] + rotation_wc[2, 1] * offset[2]
                u = int(np.floor(focal * x / z + cx + 0.5))
                v = int(np.floor(focal * y / z + cy + 0.5))
                if u < 0 or u >= width or v < 0 or v >= height:
                    continue
                if z <= depth[v, u]:
                    mask[i, j, k] = True


@numba.njit(cache=True, nogil=True)
def occupied_before_per_ray(occupied, bounds_lo, ray_of_cell, keys, t_out, t_limit, n_rays):
    """(n_rays,) int64: per ray, how many of its cells (``keys``, (C, 3)) it leaves before ``t_limit[ray]``
    inside an ``occupied`` voxel (a dense (X, Y, Z) bool volume whose first voxel has key ``bounds_lo``)."""
    counts = np.zeros(n_rays, dtype=np.int64)
    nx, ny, nz = occupied.shape
    for i in range(keys.shape[0]):
        if t_out[i] < t_limit[ray_of_cell[i]]:
            x = keys[i, 0] - bounds_lo[0]
            y = keys[i, 1] - bounds_lo[1]
            z = keys[i, 2] - bounds_lo[2]
            if 0 <= x < nx and 0 <= y < ny and 0 <= z < nz and occupied[x, y, z]:
                counts[ray_of_cell[i]] += 1
    return counts
