"""Poses and stamps of a ROS bag's messages: pairing by nearest stamp, pose samples as series, interpolation at an image stamp (linear in
position, slerp in rotation, refused across large gaps) and ``/tf`` + ``/tf_static`` chains composed edge by edge."""

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from prismap.errors import PrismapInputError


def _stamp_ns(header):
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _seconds(stamp_ns):
    """A stamp in nanoseconds as exact decimal seconds, for messages."""
    return f"{int(stamp_ns) // 1_000_000_000}.{int(stamp_ns) % 1_000_000_000:09d}"


def _pose_series(items, topic):
    """``(stamps ns, translations (N, 3), Rotation)`` of an Odometry or PoseStamped topic."""
    if not items:
        raise PrismapInputError(f"topic {topic} has no pose messages")
    poses = [msg.pose.pose if hasattr(msg, "child_frame_id") else msg.pose for _, _, msg in items]
    stamps = np.array([stamp for stamp, _, _ in items], dtype=np.int64)
    translations = np.array([[p.position.x, p.position.y, p.position.z] for p in poses])
    quaternions = np.array([[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in poses])
    return _series(stamps, translations, quaternions, topic)


def _series(stamps, translations, quaternions, what):
    norms = np.linalg.norm(quaternions, axis=1)
    if not np.all(np.isfinite(translations)) or not np.all(np.abs(norms - 1) < 1e-3):
        raise PrismapInputError(
            f"{what}: poses must be finite with unit quaternions; got norms in [{norms.min():.6g}, {norms.max():.6g}]"
        )
    stamps, first = np.unique(stamps, return_index=True)
    return stamps, translations[first], Rotation.from_quat(quaternions[first])


def _interpolate(series, stamps_ns, max_gap_s, what):
    """(N, 4, 4) poses of ``series`` at ``stamps_ns``: linear position, slerp rotation, bounded gap."""
    times, translations, rotations = series
    t = np.asarray(stamps_ns, dtype=np.int64)
    after = np.searchsorted(times, t)
    exact = (after < times.size) & (times[np.minimum(after, times.size - 1)] == t)
    inside = (after > 0) & (after < times.size)
    gap = np.where(inside, times[np.clip(after, 1, times.size - 1)] - times[np.clip(after - 1, 0, times.size - 1)], 0)
    bad = ~exact & (~inside | (gap > max_gap_s * 1e9))
    if np.any(bad):
        stamp = t[np.argmax(bad)]
        raise PrismapInputError(
            f"{what}: no pose within {max_gap_s} s around the image stamp {_seconds(stamp)} s (samples span "
            f"{_seconds(times[0])}-{_seconds(times[-1])} s; {int(bad.sum())} image(s) without a pose)"
        )
    seconds = (times - times[0]) * 1e-9
    query = (t - times[0]) * 1e-9
    poses = np.tile(np.eye(4), (t.size, 1, 1))
    for axis in range(3):
        poses[:, axis, 3] = np.interp(query, seconds, translations[:, axis])
    poses[:, :3, :3] = (
        Slerp(seconds, rotations)(query) if times.size > 1 else rotations[np.zeros(t.size, int)]
    ).as_matrix()
    return poses


def _tf_poses(dynamic, static, frames, stamps_ns, max_gap_s):
    """``T_world_cam`` at ``stamps_ns`` from ``/tf`` and ``/tf_static`` messages: WORLD -> ... -> CAMERA, edge by edge.

    A dynamic edge is interpolated at each stamp (:func:`_interpolate`); a static one holds its last value.
    """
    world, camera = frames
    edges = {}  # child -> (parent, [(stamp, translation, quaternion)], static)
    for items, is_static in ((dynamic, False), (static, True)):
        for _, _, msg in items:
            for transform in msg.transforms:
                child, parent = transform.child_frame_id.strip("/"), transform.header.frame_id.strip("/")
                t, q = transform.transform.translation, transform.transform.rotation
                entry = edges.setdefault(child, (parent, [], is_static))
                if entry[0] != parent or entry[2] != is_static:
                    raise PrismapInputError(
                        f"/tf: frame {child!r} has two parents or is both static and dynamic ({entry[0]!r}, {parent!r})"
                    )
                entry[1].append((_stamp_ns(transform.header), [t.x, t.y, t.z], [q.x, q.y, q.z, q.w]))
    world, camera = world.strip("/"), camera.strip("/")

    def chain(frame):
        path = [frame]
        while path[-1] in edges:
            path.append(edges[path[-1]][0])
            if len(path) > len(edges) + 1:
                raise PrismapInputError(f"/tf: the frames above {frame!r} form a loop")
        return path

    up_camera, up_world = chain(camera), chain(world)
    common = next((f for f in up_camera if f in up_world), None)
    if common is None:
        raise PrismapInputError(
            f"/tf, /tf_static: no chain of transforms joins frames {world!r} and {camera!r}; "
            f"known frames are {sorted(set(edges) | {p for p, _ in edges.values()})}"
        )

    def to_ancestor(path):
        """(N, 4, 4) T_ancestor_frame along ``path`` (frame first, ancestor last)."""
        T = np.tile(np.eye(4), (len(stamps_ns), 1, 1))
        for child in path[:-1]:
            parent, samples, is_static = edges[child]
            samples = sorted(samples, key=lambda s: s[0])
            what = f"{'/tf_static' if is_static else '/tf'} {parent} -> {child}"
            if is_static:
                samples = samples[-1:]
            stamps = np.array([s[0] for s in samples], dtype=np.int64)
            series = _series(stamps, np.array([s[1] for s in samples]), np.array([s[2] for s in samples]), what)
            if is_static:
                step = np.eye(4)
                step[:3, :3], step[:3, 3] = series[2].as_matrix()[0], series[1][0]
            else:
                step = _interpolate(series, stamps_ns, max_gap_s, what)
            T = step @ T
        return T

    T_common_cam = to_ancestor(up_camera[: up_camera.index(common) + 1])
    T_common_world = to_ancestor(up_world[: up_world.index(common) + 1])
    return np.linalg.inv(T_common_world) @ T_common_cam


def _pair(first, second, first_topic, second_topic, tolerance_s, *, both=True):
    """Indices ``(i, j)`` pairing each message of ``first`` with the nearest-stamped one of ``second``.

    Raises when a message of ``first`` (and, with ``both``, of ``second``) has no partner within
    ``tolerance_s``, or two of ``first`` would share one of ``second``.
    """
    a = np.array([item[0] for item in first], dtype=np.int64)
    b = np.array([item[0] for item in second], dtype=np.int64)
    tolerance_ns = round(tolerance_s * 1e9)
    if b.size == 0:
        raise PrismapInputError(f"topic {second_topic} has no messages to pair with {first_topic}")
    j = np.clip(np.searchsorted(b, a), 1, max(1, b.size - 1)) if b.size > 1 else np.zeros(a.size, dtype=np.intp)
    if b.size > 1:
        j = np.where(np.abs(b[j - 1] - a) <= np.abs(b[j] - a), j - 1, j)
    far = np.abs(b[j] - a) > tolerance_ns
    if np.any(far):
        stamp = a[np.argmax(far)]
        raise PrismapInputError(
            f"topic {first_topic}: the message at stamp {_seconds(stamp)} s has no partner on {second_topic} "
            f"within {tolerance_s} s ({int(far.sum())} unpaired)"
        )
    if np.unique(j).size != j.size:
        raise PrismapInputError(
            f"topics {first_topic} and {second_topic}: two messages pair with one; "
            f"lower the pairing tolerance (now {tolerance_s} s)"
        )
    if both and j.size != b.size:
        lonely = np.setdiff1d(np.arange(b.size), j)[0]
        raise PrismapInputError(
            f"topic {second_topic}: the message at stamp {_seconds(b[lonely])} s has no partner on {first_topic} "
            f"within {tolerance_s} s ({b.size - j.size} unpaired)"
        )
    return np.arange(a.size), j
