"""Texture bank of the 3-D scenes: scikit-image's bundled photographs plus seeded procedural noise."""

from __future__ import annotations

import functools

import cv2
import numpy as np
import numpy.typing as npt

TEXTURE_SIZE = 256
PHOTOGRAPHS = ("astronaut", "camera", "coffee", "chelsea", "rocket", "brick", "grass", "gravel")
N_NOISE = 4
OTHER_PHOTOGRAPHS = (
    "hubble_deep_field",
    "immunohistochemistry",
    "coins",
    "page",
    "moon",
    "retina",
    "text",
    "clock",
    "cell",
    "checkerboard",
)
"""Photographs only the avenue world wears (bank indices from :data:`FIRST_OTHER`), so that a model tuned on the
street meets textures it never saw; ``checkerboard`` is a repeated pattern, a matcher's classic failure."""
FIRST_OTHER = len(PHOTOGRAPHS) + N_NOISE
"""Bank index of the first of :data:`OTHER_PHOTOGRAPHS`: the room and the street draw textures below it."""


@functools.lru_cache(maxsize=1)
def texture_bank() -> npt.NDArray[np.float32]:
    """(T, 256, 256, 3) float32 in [0, 1], read-only: the photographs of ``PHOTOGRAPHS`` in order (grey ones
    as three equal channels, contrast-stretched), then ``N_NOISE`` multi-octave value-noise textures (fixed seed),
    then the photographs of ``OTHER_PHOTOGRAPHS``.
    """
    textures = [_photograph(name) for name in PHOTOGRAPHS]
    rng = np.random.default_rng(20150601)
    for _ in range(N_NOISE):
        noise = np.zeros((TEXTURE_SIZE, TEXTURE_SIZE), dtype=np.float32)
        for octave in range(2, 8):
            cells = 2**octave
            coarse = rng.random((cells, cells)).astype(np.float32)
            tiled = np.tile(coarse, (3, 3))  # resize a 3x3 tiling and keep the middle: the texture wraps seamlessly
            big = cv2.resize(tiled, (3 * TEXTURE_SIZE, 3 * TEXTURE_SIZE), interpolation=cv2.INTER_CUBIC)
            noise += big[TEXTURE_SIZE : 2 * TEXTURE_SIZE, TEXTURE_SIZE : 2 * TEXTURE_SIZE] / 1.6 ** (7 - octave)
        noise = (noise - noise.min()) / (noise.max() - noise.min())
        textures.append(np.repeat(noise[..., None], 3, axis=2))
    textures += [_photograph(name) for name in OTHER_PHOTOGRAPHS]
    bank = np.ascontiguousarray(np.stack(textures), dtype=np.float32)
    bank.setflags(write=False)
    return bank


def _photograph(name):
    """scikit-image's bundled image ``name`` as a contrast-stretched (256, 256, 3) float32 texture."""
    from skimage import data

    image = np.asarray(getattr(data, name)(), dtype=np.float32)
    image = image / 255.0 if image.max() > 1.0 else image
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=2)
    image = cv2.resize(image[..., :3], (TEXTURE_SIZE, TEXTURE_SIZE), interpolation=cv2.INTER_AREA)
    low, high = np.percentile(image, [1, 99])
    return np.clip((image - low) / max(high - low, 1e-6), 0.0, 1.0)
