"""Per-frame policies: how the increments of the several rays of one frame that cross one voxel become
that voxel's single update of the frame (SENSOR_MODELS.md section 3).

The grid owns them: their names, their codes in the kernels, and the combining rule. A sensor model
only names its ``default_policy``.
"""

import numba

from prismap.errors import PrismapInputError

POLICIES = ("mean", "max-abs", "occupied-wins", "max", "sum")
"""Policy names: ``mean`` of the increments, ``max-abs`` (the one of largest magnitude), ``occupied-wins``
(the largest increment if any is positive, else the mean: with the hit/miss model this is OctoMap's rule),
``max``, ``sum``."""

POLICY_CODES = {name: code for code, name in enumerate(POLICIES)}
"""Policy name -> code used by the kernels (:func:`combine`)."""


def policy_code(policy, model):
    """Code of ``policy``, or of ``model.default_policy`` when ``policy`` is None."""
    name = model.default_policy if policy is None else policy
    if name not in POLICY_CODES:
        raise PrismapInputError(f"`policy` must be one of {list(POLICIES)}; got {name!r}")
    return POLICY_CODES[name]


def policy_name(policy, model):
    """The policy a frame runs with: ``policy``, or the model's default."""
    return model.default_policy if policy is None else policy


@numba.njit(cache=True, nogil=True, inline="always")
def combine(total, count, largest, smallest, policy):
    """One voxel's update from its frame statistics ``(sum, count, max, min)`` of increments, by ``policy``."""
    if policy == 0:
        return total / count
    if policy == 1:
        return largest if abs(largest) >= abs(smallest) else smallest
    if policy == 2:
        return largest if largest > 0.0 else total / count
    if policy == 3:
        return largest
    return total
