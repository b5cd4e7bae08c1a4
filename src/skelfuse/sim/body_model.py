"""Building blocks of the observation model, each a pure function tested against its closed form.

Noise processes (AR(1), Student-t), capsule self-occlusion, facing, the mirror and limb-swap burst chains
and the refit of noisy joints to a symmetric body model; ``skelfuse.sim.observe.simulate`` composes them.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from skelfuse.schema.skeleton import BODY_REGIONS, BONES, MIRROR, N_JOINTS, PARENTS, J
from skelfuse.sim.motion import root_facing
from skelfuse.sim.profile import CAPSULES, SimProfile

_TORSO_CAPSULE = np.array([c[0] in ("spine", "torso_side") for c in CAPSULES])
_CAN_HIDE = ~(np.isin(np.arange(N_JOINTS), BODY_REGIONS["torso"])[:, None] & _TORSO_CAPSULE)
"""(32, C) whether capsule c can hide joint j: torso joints lie inside the trunk, which the tracker sees through
its surface, so only limbs and the head can hide them."""


_LIMB_CHAINS = tuple(
    tuple(np.array([J[f"{name}_{side}"] for name in names]) for side in ("LEFT", "RIGHT"))
    for names in (("ELBOW", "WRIST", "HAND", "HANDTIP", "THUMB"), ("KNEE", "ANKLE", "FOOT"))
)
"""(left, right) joint chains of the arms and of the legs: what a single-limb left/right swap exchanges."""


def ar1(
    rng: np.random.Generator,
    n: int,
    shape: tuple[int, ...],
    rho: np.ndarray | float,
    sigma: np.ndarray | float,
    impulses: np.ndarray | None = None,
) -> np.ndarray:
    """Stationary AR(1) processes along axis 0: ``x[k] = rho x[k-1] + e[k]``, SD ``sigma``.

    Parameters
    ----------
    rng : random generator
    n : number of steps
    shape : shape of one step (the independent processes)
    rho, sigma : broadcastable to ``shape``
    impulses : optional (n, *shape) extra innovations added to ``e`` (jumps that then decay)

    Returns
    -------
    (n, *shape) float64. x[0] is drawn from the stationary distribution N(0, sigma²).
    """
    rho_arr = np.broadcast_to(np.asarray(rho, dtype=np.float64), shape)
    sigma_arr = np.broadcast_to(np.asarray(sigma, dtype=np.float64), shape)
    innovations = rng.standard_normal((n, *shape)) * (sigma_arr * np.sqrt(1.0 - rho_arr**2))
    innovations[0] = rng.standard_normal(shape) * sigma_arr
    if impulses is not None:
        innovations = innovations + impulses
    out = np.empty_like(innovations)
    for value in np.unique(rho_arr):  # one IIR filter per distinct coefficient (a handful of groups)
        mask = rho_arr == value
        out[:, mask] = lfilter([1.0], [1.0, -value], innovations[:, mask], axis=0)
    return out


def student_t(rng: np.random.Generator, shape: tuple[int, ...], sigma: np.ndarray | float, dof: float) -> np.ndarray:
    """Heavy-tailed white noise: Student-t with ``dof`` degrees of freedom scaled to SD ``sigma``."""
    return rng.standard_t(dof, size=shape) * (np.asarray(sigma) / np.sqrt(dof / (dof - 2.0)))


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest approach of segments [p0, p1] and [q0, q1], vectorized (broadcasting over leading axes).

    Returns
    -------
    distance : (...) the minimum distance
    s : (...) parameter in [0, 1] of the closest point on [p0, p1]

    References
    ----------
    C. Ericson, Real-Time Collision Detection (2005), 5.1.9 ClosestPtSegmentSegment.
    """
    # The dot products broadcast as they go (a ray's length once per ray, not once per ray and capsule); the
    # results still take the broadcast shape of all four inputs, through r, d1 x d2 and the products below.
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0

    def dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.einsum("...k,...k->...", u, v)

    a, e, f, c, b = dot(d1, d1), dot(d2, d2), dot(d2, r), dot(d1, r), dot(d1, d2)
    eps = 1e-12
    a_safe = np.maximum(a, eps)
    e_safe = np.maximum(e, eps)
    ae = a * e
    denom = ae - b * b
    s = np.where(denom > eps * np.maximum(ae, eps), np.clip((b * f - c * e) / np.maximum(denom, eps), 0, 1), 0.0)
    t = (b * s + f) / e_safe
    s = np.where(t < 0, np.clip(-c / a_safe, 0, 1), np.where(t > 1, np.clip((b - c) / a_safe, 0, 1), s))
    t = np.clip(t, 0, 1)
    degenerate_q = e <= eps  # a sphere: closest point on p to q0
    if degenerate_q.any():
        s = np.where(degenerate_q, np.clip(-c / a_safe, 0, 1), s)
        t = np.where(degenerate_q, 0.0, t)
    # |r + s d1 - t d2|² expanded, so no (..., 3) temporaries are needed
    squared = dot(r, r) + s * s * a + t * t * e + 2 * s * c - 2 * t * f - 2 * s * t * b
    return np.sqrt(np.maximum(squared, 0.0)), s


def self_occlusion(points: np.ndarray, radii: dict[str, float], margin_mm: float) -> np.ndarray:
    """Which joints the body itself hides from a camera at the origin.

    Parameters
    ----------
    points : (T, 32, 3) true joints in the camera frame, mm
    radii : capsule radius per key of :data:`CAPSULES`, mm
    margin_mm : the occluding surface must lie at least this far in front of the joint along the ray

    Returns
    -------
    (T, 32) bool: the ray from the camera to the joint passes through a capsule that does not contain the
    joint, at a point nearer the camera than the joint by at least ``margin_mm``.
    """
    starts = points[:, [J[c[1]] for c in CAPSULES]][:, None]  # (T, 1, C, 3)
    ends = points[:, [J[c[2]] for c in CAPSULES]][:, None]
    radius = np.array([radii[c[0]] for c in CAPSULES])  # (C,)
    joints = points[:, :, None, :]  # (T, 32, 1, 3)
    origin = np.zeros(3)  # the camera; broadcast, so the ray-independent terms are formed once per capsule
    ray_dist, s = segment_distance(origin, joints, starts, ends)  # (T, 32, C)
    depth = np.linalg.norm(joints, axis=-1)  # (T, 32, 1)
    in_front = (ray_dist < radius) & (s * depth < depth - margin_mm) & _CAN_HIDE
    # Whether the joint lies inside the capsule, only where the ray passes through it in front of the joint (a
    # small share of the (frame, joint, capsule) triples; the same numbers as over all of them, at half the cost).
    t, j, c = np.nonzero(in_front)
    inside, _ = segment_distance(points[t, j], points[t, j], starts[t, 0, c], ends[t, 0, c])
    hides = np.zeros_like(in_front)
    hides[t, j, c] = inside > radius[c]
    return hides.any(axis=-1)


def facing_away_deg(truth: np.ndarray, sensor_position: np.ndarray) -> np.ndarray:
    """(T,) angle between the body's facing and the horizontal direction to the sensor, degrees (0 = faces it)."""
    forward = root_facing(truth)
    to_sensor = sensor_position[None, :] - truth[:, J["PELVIS"]]
    to_sensor[:, 2] = 0.0
    to_sensor /= np.maximum(np.linalg.norm(to_sensor, axis=1, keepdims=True), 1e-9)
    return np.degrees(np.arccos(np.clip(np.sum(forward * to_sensor, axis=1), -1.0, 1.0)))


def mirror_bursts(
    rng: np.random.Generator, angle_deg: np.ndarray, tracked: np.ndarray, profile: SimProfile
) -> np.ndarray:
    """(T,) bool: left/right flip bursts, a Markov chain driven by the facing angle (with hysteresis)."""
    uniform = rng.random(angle_deg.size)
    away = angle_deg > profile.away_threshold_deg
    hold_from = profile.away_threshold_deg - profile.hysteresis_deg
    if profile.side_flip_prob > 0:  # failure family "side_flips": side views flip too, and hold while sideways
        hold_from = min(hold_from, profile.side_flip_min_deg)
    holdable = angle_deg > hold_from
    side = (angle_deg > profile.side_flip_min_deg) & ~away
    free = angle_deg <= profile.front_free_deg
    out = np.zeros(angle_deg.size, dtype=bool)
    state = False
    for k in range(angle_deg.size):  # scalar state machine over frames; numpy would not help here
        if not tracked[k] or free[k]:
            state = False
        elif state:
            p_off = profile.flip_off_prob_away if holdable[k] else profile.flip_off_prob_front
            state = uniform[k] >= p_off
        elif away[k]:
            state = uniform[k] < profile.flip_on_prob
        elif side[k]:
            state = uniform[k] < profile.side_flip_prob
        out[k] = state
    return out


def limb_swap_bursts(
    rng: np.random.Generator, angle_deg: np.ndarray, eligible: np.ndarray, profile: SimProfile
) -> np.ndarray:
    """(T, 2) bool: bursts in which one limb pair (column 0 the arms, 1 the legs) has its left and right labels
    swapped, in views that do not see the body from behind (failure family "limb_swaps"; the case the paper's
    per-pair realignment targets). Each starts with ``limb_swap_prob`` per frame and pair and ends with
    ``limb_swap_off_prob``."""
    n = angle_deg.size
    out = np.zeros((n, 2), dtype=bool)
    if profile.limb_swap_prob <= 0:
        return out
    uniform = rng.random((n, 2))
    allowed = eligible & (angle_deg <= profile.away_threshold_deg)
    state = np.zeros(2, dtype=bool)
    for k in range(n):  # a two-state chain per pair, vectorized over the pairs
        state = np.where(state, uniform[k] >= profile.limb_swap_off_prob, uniform[k] < profile.limb_swap_prob)
        state &= allowed[k]
        out[k] = state
    return out


def _swap_limbs(
    lab: np.ndarray, hidden: np.ndarray, in_view: np.ndarray, swaps: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Swap the left/right labels of the arm (``swaps[:, 0]``) and leg (``swaps[:, 1]``) chains where set."""
    if not swaps.any():
        return lab, hidden, in_view
    lab, hidden, in_view = lab.copy(), hidden.copy(), in_view.copy()
    for column, (left, right) in enumerate(_LIMB_CHAINS):
        frames = swaps[:, column]
        for array in (lab, hidden, in_view):
            left_values = array[frames][:, left].copy()
            array[np.ix_(frames, left)] = array[frames][:, right]
            array[np.ix_(frames, right)] = left_values
    return lab, hidden, in_view


def symmetric_bone_lengths(truth: np.ndarray) -> np.ndarray:
    """(32,) the tracker's template length of the bone ending at each joint (median over frames, left and
    right averaged: the body model is symmetric). Entry 0 (pelvis) is zero."""
    lengths = np.zeros(N_JOINTS)
    lengths[BONES[:, 1]] = np.median(np.linalg.norm(truth[:, BONES[:, 1]] - truth[:, BONES[:, 0]], axis=-1), axis=0)
    return 0.5 * (lengths + lengths[MIRROR])


_IK_CHILD = {
    J[f"{joint}_{side}"]: J[f"{child}_{side}"]
    for side in ("LEFT", "RIGHT")
    for joint, child in (("ELBOW", "WRIST"), ("WRIST", "HAND"), ("KNEE", "ANKLE"), ("ANKLE", "FOOT"))
}
"""A limb joint and the child that continues its chain: a guessed joint is placed so that this child, when the
tracker sees it, stays where it was seen (two-bone IK in :func:`fit_body_model`)."""


def fit_body_model(
    noisy: np.ndarray, bone_lengths: np.ndarray, scale: np.ndarray, guessed: np.ndarray | None = None
) -> np.ndarray:
    """Refit joints to a body model with fixed bone lengths times one size factor per frame.

    Walks the kinematic chain from the pelvis: each joint goes ``scale * length`` away from its already
    fitted parent, in the direction of its noisy position. A guessed limb joint (``guessed``: hidden or lost)
    whose chain child (:data:`_IK_CHILD`: elbow -> wrist, wrist -> hand, knee -> ankle, ankle -> foot) is
    not guessed is placed by two-bone IK instead: on the circle of positions that keep both bone lengths and
    put the child where it was seen (as near as the two bones reach), on the side of its own guess. A model
    fitter anchors a hidden elbow to the wrist it sees; walking the chain would instead carry the elbow's
    guess error, redrawn at every jump, down to the visible wrist and hand.

    Parameters
    ----------
    noisy : (T, 32, 3) joints, mm
    bone_lengths : (32,) template length of the bone ending at each joint, mm
    scale : (T,) size factor
    guessed : (T, 32) bool or None, joints the tracker guessed (None: none)

    Returns
    -------
    (T, 32, 3): every bone's length is exactly ``scale[t] * bone_lengths[j]``.
    """
    out = np.empty_like(noisy)
    out[:, 0] = noisy[:, 0]
    for joint in range(1, N_JOINTS):
        parent = PARENTS[joint]
        length = scale * bone_lengths[joint]
        direction = noisy[:, joint] - out[:, parent]
        norm = np.linalg.norm(direction, axis=1, keepdims=True)
        direction = np.where(norm > 1e-9, direction / np.maximum(norm, 1e-9), np.array([0.0, 1.0, 0.0]))
        out[:, joint] = out[:, parent] + direction * length[:, None]
        child = _IK_CHILD.get(joint)
        if guessed is not None and child is not None:
            rows = guessed[:, joint] & ~guessed[:, child]
            if rows.any():
                out[rows, joint] = _two_bone(
                    out[rows, parent],
                    noisy[rows, child],
                    out[rows, joint],
                    length[rows],
                    (scale * bone_lengths[child])[rows],
                )
    return out


def _two_bone(root: np.ndarray, target: np.ndarray, hint: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3) the middle joint of a two-bone chain ``root -(a)- middle -(b)- end`` with the end as near ``target``
    as the bones reach, on the side of ``hint`` (the plane through root, target and hint)."""
    axis = target - root
    d = np.linalg.norm(axis, axis=1)
    u = np.where(d[:, None] > 1e-9, axis / np.maximum(d, 1e-9)[:, None], np.array([0.0, 0.0, 1.0]))
    d = np.clip(d, np.abs(a - b) + 1e-6, a + b - 1e-6)
    along = (a * a - b * b + d * d) / (2.0 * d)
    radius = np.sqrt(np.maximum(a * a - along * along, 0.0))
    side = hint - root
    side = side - np.sum(side * u, axis=1, keepdims=True) * u
    norm = np.linalg.norm(side, axis=1, keepdims=True)
    other = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])))
    side = np.where(norm > 1e-9, side / np.maximum(norm, 1e-9), other / np.linalg.norm(other, axis=1, keepdims=True))
    return root + along[:, None] * u + radius[:, None] * side
