"""Shapes shared by the rigid registration tests: a scan-like surface with no symmetry, and a far,
partial pair of it with a known motion (made here, independent of the library)."""
import numpy as np
from scipy.spatial.transform import Rotation


def bumpy(xy):
    """A scan-like height field over (N, 2) ``xy`` with bumps of different sizes and heights: no symmetry."""
    z = 0.1 * np.sin(5 * xy[:, 0]) * xy[:, 1]
    for (cx, cy), height, width in (((0.3, 0.2), 0.4, 10), ((-0.5, 0.4), 0.3, 20), ((0.1, -0.6), 0.35, 15),
                                    ((-0.3, -0.2), -0.25, 25), ((0.7, -0.1), 0.2, 30), ((-0.7, -0.7), 0.3, 12)):
        z = z + height * np.exp(-width * ((xy[:, 0] - cx) ** 2 + (xy[:, 1] - cy) ** 2))
    return np.c_[xy, z]


def far_partial_pair(seed=0):
    """Two samples of the bumpy surface overlapping on x in [-0.5, 0.5] (2/3 of each), the target
    rotated by 130 degrees about a random axis: far beyond what the centroid start reaches.

    Returns (model, seen, target, rot, trans): ``target = seen @ rot.T + trans`` plus noise.
    """
    rng = np.random.default_rng(seed)
    model = bumpy(rng.uniform(-1, 1, (3000, 2)))
    model = model[model[:, 0] < 0.5]
    seen = bumpy(rng.uniform(-1, 1, (3000, 2)))
    seen = seen[seen[:, 0] > -0.5]
    axis = rng.normal(size=3)
    rot = Rotation.from_rotvec(np.deg2rad(130) * axis / np.linalg.norm(axis)).as_matrix()
    trans = np.array([0.3, -0.5, 0.8])
    target = seen @ rot.T + trans + rng.normal(scale=0.003, size=seen.shape)
    return model, seen, target, rot, trans
