"""How PRISM's tables space their nodes for a given error mixture: fine where the evidence changes, coarse where
only the widest error component produces the measurement (see docs/SENSOR_MODELS.md, "The tables").

Node spacings are in the integration coordinate ``x`` (one unit per prior e-fold or narrowest sigma of disparity).
"""

import numpy as np

_TABLE_STEP = 0.5  # table node spacing in x, also the width of its march's panels
_COARSE_RATIO = 64  # node spacing 32 in x where log(C/Z) < _COARSE_BELOW (near-quadratic in x) and past influence
_COARSE_WIDE_SIGMAS = 0.125  # coarse-front node spacing may reach this many widest sigmas (see coarse_ratio)
_COARSE_BELOW = -40.0
_BROAD_SHARE = -20.0  # log share of g below which a table's broad front drops the narrower error components
_WIDE_SIGMAS = 0.25  # broad-front node spacing, at most this many sigmas of the narrowest wide component
_WIDE_KEEP = 0.5  # wide error components: sigma at least this share of the widest (kept in a broad segment)


def coarse_ratio(mixture):
    """Fine nodes per node of a PRISM table's coarse front (where ``C/Z < e^_COARSE_BELOW``).

    There the measurement is far behind, only the widest error component produces it and ``log(q g)`` is nearly
    quadratic in ``x``: :data:`_COARSE_RATIO`, or, when the mixture's sigmas span more than that allows, nodes
    :data:`_COARSE_WIDE_SIGMAS` widest sigmas of disparity apart (a characterised class with a component of
    0.01 px beside outliers of 33 px would otherwise put thousands of nodes between ``near_m`` and the
    measurement's first evidence). Mixtures whose widest sigma is below 256 narrowest ones keep
    :data:`_COARSE_RATIO`.
    """
    sd = mixture.sigmas
    return max(_COARSE_RATIO, int(_COARSE_WIDE_SIGMAS * sd.max() / (sd.min() * _TABLE_STEP)))


def broad_errors(mixture):
    """Where a PRISM table may drop its narrow error components, and its node spacing there.

    The wide components are those whose sigma is at least :data:`_WIDE_KEEP` of the widest one's (a
    characterised mixture often holds two: a class's own outlier component and the whole image's); the others
    are narrow. For errors ``e >= e_front`` (pixels; true disparity above ``d^ + e_front``, in front of the
    measurement) and ``e <= e_back`` (behind it) every narrow component's density is below ``e^_BROAD_SHARE`` of
    the widest one's, so ``C``, ``D`` and their moments there are smooth on the narrowest wide sigma's scale:
    nodes every ``wide_ratio`` fine nodes (at most ``_WIDE_SIGMAS`` of that sigma apart). ``wide_ratio`` 1 (a
    one-component mixture, or one whose components are all wide): no broad segments.

    Parameters
    ----------
    mixture : GaussianMixture
        Disparity error ``e = d_true - d_computed`` (pixels).

    Returns
    -------
    e_front, e_back : float, pixels (``inf``, ``-inf``: none; ``-inf``, ``inf``: everywhere)
    wide_ratio : int >= 1
    """
    w, mu, sd = mixture.weights, mixture.means, mixture.sigmas
    b = int(np.argmax(sd))
    wide = sd >= _WIDE_KEEP * sd[b]
    if wide.all():
        return np.inf, -np.inf, 1
    e_front, e_back = -np.inf, np.inf
    for j in np.flatnonzero(~wide):
        # log(w_j N_j(e)) - log(w_b N_b(e)) - _BROAD_SHARE = a e^2 + b e + c, a < 0: it is < 0 outside its roots
        a = 0.5 / sd[b] ** 2 - 0.5 / sd[j] ** 2
        lin = mu[j] / sd[j] ** 2 - mu[b] / sd[b] ** 2
        c = (
            np.log(w[j] / sd[j])
            - np.log(w[b] / sd[b])
            - 0.5 * (mu[j] / sd[j]) ** 2
            + 0.5 * (mu[b] / sd[b]) ** 2
            - _BROAD_SHARE
        )
        disc = lin * lin - 4.0 * a * c
        if disc > 0:
            e_front = max(e_front, (-lin - np.sqrt(disc)) / (2.0 * a))
            e_back = min(e_back, (-lin + np.sqrt(disc)) / (2.0 * a))
    wide_ratio = int(_WIDE_SIGMAS * sd[wide].min() / (sd.min() * _TABLE_STEP))
    return float(e_front), float(e_back), max(min(wide_ratio, _COARSE_RATIO), 1)
