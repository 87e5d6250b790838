"""Evaluation metrics: Guo et al.'s text-to-motion metrics on evaluator embeddings (FID,
diversity, R-precision, MM-Dist, multimodality), M2D2M's transition Jerk (paper eq. 10) on
joint positions, and FlowMDM's Peak Jerk and Area Under the Jerk (Barquero et al., CVPR 2024).

The embedding metrics follow Guo et al.'s protocol (EricGuo5513/text-to-motion, ``utils/metrics.py``) so
that numbers
from the same evaluator are comparable with published tables. Everything is computed in float64
NumPy: metrics run once per evaluation, where precision matters more than speed. Inputs may be
NumPy arrays or torch tensors; results are Python floats or NumPy arrays.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence

import numpy as np
import torch

CI95_Z = 1.96  # normal quantile: the 95 % interval's factor when the repeats are many (sizing them)
CONFIDENCE = 0.95
DEFAULT_MIN_STEP = 5e-5  # largest frame-to-frame move (metres) of a "still" joint: 1 mm/s at 20 fps


def _as_array(values, name: str, ndim: int | None = None) -> np.ndarray:
    """A finite float64 NumPy copy of ``values`` of the expected rank; torch tensors leave their
    device here, so callers can pass evaluator outputs as they come."""
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().double().numpy()
    array = np.asarray(values, dtype=np.float64)
    if ndim is not None and array.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return array


def _paired(text_emb, motion_emb) -> tuple[np.ndarray, np.ndarray]:
    """Text and motion embeddings (N, D) whose row i describe the same sample."""
    text = _as_array(text_emb, "text_emb", 2)
    motion = _as_array(motion_emb, "motion_emb", 2)
    if text.shape != motion.shape:
        raise ValueError(f"text_emb {text.shape} and motion_emb {motion.shape} must pair row by row (same shape)")
    if len(text) == 0:
        raise ValueError("text_emb and motion_emb are empty")
    return text, motion


def _psd_sqrt(matrix: np.ndarray) -> np.ndarray:
    """Square root of a symmetric positive semi-definite matrix; round-off negatives become 0."""
    eigenvalues, eigenvectors = np.linalg.eigh(matrix)
    return (eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))) @ eigenvectors.T


def fid(feats_a, feats_b) -> float:
    """Fréchet distance between Gaussians fitted to two feature sets (N, D):
    ``‖μa − μb‖² + tr(Σa + Σb − 2 (Σa Σb)^½)``, covariances normalised by N − 1 (``np.cov``).

    tr((Σa Σb)^½) is the sum of the square roots of the eigenvalues of Σa^½ Σb Σa^½, a symmetric
    PSD matrix with the eigenvalues of Σa Σb. Symmetric eigendecompositions stay real and stable
    where a general matrix square root returns complex noise for singular covariances (fewer
    samples than dimensions). Round-off can leave the result a hair below 0; it is clamped.
    """
    a = _as_array(feats_a, "feats_a", 2)
    b = _as_array(feats_b, "feats_b", 2)
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"feats_a and feats_b must have the same feature size, got {a.shape[1]} and {b.shape[1]}")
    for name, feats in (("feats_a", a), ("feats_b", b)):
        if len(feats) < 2:
            raise ValueError(f"fid needs at least 2 samples in {name} to fit a covariance, got {len(feats)}")
    cov_a = np.atleast_2d(np.cov(a, rowvar=False))
    cov_b = np.atleast_2d(np.cov(b, rowvar=False))
    root_a = _psd_sqrt(cov_a)
    cross = np.linalg.eigvalsh(root_a @ cov_b @ root_a)
    trace_sqrt = np.sqrt(np.clip(cross, 0.0, None)).sum()
    shift = a.mean(0) - b.mean(0)
    return max(float(shift @ shift + np.trace(cov_a) + np.trace(cov_b) - 2.0 * trace_sqrt), 0.0)


def diversity(feats, pairs: int = 300, seed: int = 0) -> float:
    """Mean Euclidean distance over ``pairs`` random pairs of samples (Guo et al.): two index
    sets of size ``pairs``, each drawn without replacement from the N samples, paired position by
    position. As in Guo's code a pair may join a sample with itself (distance 0).

    Fewer samples than ``pairs`` is an error rather than a silent shrink, because the number of
    pairs changes the statistic; a small (demo) set passes a smaller ``pairs`` explicitly.
    """
    feats = _as_array(feats, "feats", 2)
    if pairs < 1:
        raise ValueError(f"pairs must be at least 1, got {pairs}")
    if len(feats) < pairs:
        raise ValueError(
            f"diversity with pairs={pairs} needs at least {pairs} samples, got "
            f"{len(feats)}; pass a smaller pairs for small sets"
        )
    rng = np.random.default_rng(seed)
    first = rng.choice(len(feats), pairs, replace=False)
    second = rng.choice(len(feats), pairs, replace=False)
    return float(np.linalg.norm(feats[first] - feats[second], axis=1).mean())


def _match_ranks(distances: np.ndarray) -> np.ndarray:
    """0-based rank of each row's diagonal entry in that row, ties broken like a stable argsort:
    an equal distance at a lower column index ranks first."""
    own = np.diag(distances)[:, None]
    closer = (distances < own).sum(1)
    tied_before = np.tril(distances == own, k=-1).sum(1)
    return closer + tied_before


def r_precision(text_emb, motion_emb, top_k: int = 3, batch: int = 32) -> np.ndarray:
    """For k = 1..top_k, the fraction of texts whose own motion is among their k nearest motions
    (Guo et al.'s R-precision; element 2 is the paper's R-Top3).

    Rows are taken in consecutive groups of ``batch``: each text competes against the other
    batch − 1 motions of its group, so the score depends on the batch size and the row order
    (Guo shuffles). The last incomplete group is dropped, as Guo's loader does (drop_last), and the
    fractions are over the rows used. Distances are Euclidean; ties are broken like a stable
    argsort (see ``_match_ranks``), which counts a tie against the match only when the tied
    motion comes first in the group.
    """
    text, motion = _paired(text_emb, motion_emb)
    if not 1 <= top_k <= batch:
        raise ValueError(f"top_k must lie in 1..batch ({batch}), got {top_k}")
    groups = len(text) // batch
    if groups == 0:
        raise ValueError(
            f"r_precision needs at least batch={batch} samples, got {len(text)}; pass a smaller batch for small sets"
        )
    hits = np.zeros(top_k)
    for start in range(0, groups * batch, batch):
        rows = slice(start, start + batch)
        distances = np.linalg.norm(text[rows, None] - motion[None, rows], axis=-1)
        hits += (_match_ranks(distances)[:, None] < np.arange(1, top_k + 1)).sum(0)
    return hits / (groups * batch)


def mm_dist(text_emb, motion_emb) -> float:
    """Mean Euclidean distance between each text embedding and its own motion's (MM-Dist, Guo's
    "matching score"). Guo averages over the rows R-precision used; pass those rows for equality."""
    text, motion = _paired(text_emb, motion_emb)
    return float(np.linalg.norm(text - motion, axis=1).mean())


def multimodality(feats_per_prompt, pairs: int = 10, seed: int = 0) -> float:
    """Mean distance between two generations of the same prompt (Guo et al.'s MModality) for
    features (P prompts, R generations, D): two index sets of size ``pairs`` drawn without
    replacement from the R generations — one draw shared by every prompt, as in Guo's code —
    averaged over prompts and pairs. A pair may join a generation with itself (distance 0)."""
    feats = _as_array(feats_per_prompt, "feats_per_prompt", 3)
    if len(feats) == 0:
        raise ValueError("feats_per_prompt has no prompts")
    if pairs < 1:
        raise ValueError(f"pairs must be at least 1, got {pairs}")
    if feats.shape[1] < pairs:
        raise ValueError(
            f"multimodality with pairs={pairs} needs at least {pairs} generations per prompt, got {feats.shape[1]}"
        )
    rng = np.random.default_rng(seed)
    first = rng.choice(feats.shape[1], pairs, replace=False)
    second = rng.choice(feats.shape[1], pairs, replace=False)
    return float(np.linalg.norm(feats[:, first] - feats[:, second], axis=-1).mean())


def transition_windows(x, boundaries: Sequence[int], window: int = 40) -> list[np.ndarray]:
    """The ``window`` frames centred on each boundary of a sequence ``x`` (F, ...): frames
    ``b − window // 2`` up to ``b − window // 2 + window − 1`` — for 40, the 20 frames before the
    boundary and the 20 from it on, the transition span of the paper's Fig. 3 — clipped to the
    sequence, so a window near either end is shorter.

    A boundary is the index of the first frame of the next action (0 < b < F). The windows come
    back as a list in the order of ``boundaries`` because clipped ones differ in length;
    ``np.stack`` it when none is clipped (e.g. for transition FID / diversity features).
    """
    frames = _as_array(x, "x")
    if frames.ndim == 0:
        raise ValueError("x must have a frame axis, got a scalar")
    if window < 1:
        raise ValueError(f"window must be at least 1 frame, got {window}")
    if len(boundaries) == 0:
        raise ValueError("boundaries is empty: a transition window needs at least one boundary")
    windows = []
    for boundary in boundaries:
        try:
            boundary = operator.index(boundary)
        except TypeError:
            raise ValueError(f"boundaries must be integer frame indices, got {boundary!r}") from None
        if not 0 < boundary < len(frames):
            raise ValueError(
                f"boundary {boundary} lies outside the sequence's interior "
                f"(1..{len(frames) - 1} for {len(frames)} frames)"
            )
        start = boundary - window // 2
        windows.append(frames[max(start, 0) : start + window])
    return windows


def dimensionless_jerk(positions, fps: float, min_step: float = DEFAULT_MIN_STEP) -> np.ndarray:
    """Per joint of a clip (F, J, 3), the quantity inside the logarithm of the paper's eq. 10:
    ``(1 / v_peak²) ∫ ‖da/dt‖² dt`` over the whole clip; NaN for a still joint — one that never
    moves ``min_step`` or more between two frames — where the ratio tends to 0/0 and only
    measures noise. The threshold is per frame so that the choice of ``fps`` cannot change it.

    Derivatives are forward differences times ``fps`` (F − 1 velocities, F − 3 jerk samples); the
    integral is the mean squared jerk times the clip's duration (F − 1) / fps, which is exact for
    constant jerk; v_peak is the largest of the finite-difference speeds. Scaling the positions
    leaves the value unchanged. Eq. 10, unlike Hogan's dimensionless jerk, has no duration³
    factor, so the value is in s⁻³ and depends on the clip length — a constant shift for the
    fixed-length windows it is used on.
    """
    positions = _as_array(positions, "positions", 3)
    if positions.shape[2] != 3:
        raise ValueError(f"positions must be (frames, joints, 3), got shape {positions.shape}")
    if len(positions) < 4:
        raise ValueError(f"a third derivative needs at least 4 frames, got {len(positions)}")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    velocity = np.diff(positions, axis=0) * fps
    jerk_samples = np.diff(velocity, n=2, axis=0) * fps**2
    duration = (len(positions) - 1) / fps
    integral = (jerk_samples**2).sum(-1).mean(0) * duration
    peak_speed = np.linalg.norm(velocity, axis=-1).max(0)
    moving = peak_speed >= min_step * fps
    return np.where(moving, integral / np.where(moving, peak_speed, 1.0) ** 2, np.nan)


def jerk(joints, fps: float, boundaries: Sequence[int], window: int = 40, min_step: float = DEFAULT_MIN_STEP) -> float:
    """The paper's transition Jerk (eq. 10) of one multi-action sequence of joint positions
    (F, J, 3) in metres, with ``boundaries`` the first frames of actions 2..N.

    For each boundary, [t1, t2] is its ``transition_windows`` window (``window`` frames centred
    on it, clipped to the sequence) and, for each joint p,
    ``ln((1 / v²_{p,peak}) ∫_{t1}^{t2} ‖d a_p/dt‖² dt)`` is computed on that window alone
    (``dimensionless_jerk``; v_peak is the joint's peak speed inside the window). These logs are
    AVERAGED over joints — eq. 10 writes Σ_p, but the text says the value "is calculated for
    each joint and then averaged" and "take[s] the average of these values", and an average does
    not grow with the joint count (22 for HumanML3D, 21 for KIT) — and then averaged over the
    boundaries, as the paper's "Mean Jerk of all transitions". A test set's value is the mean of
    this over its sequences, left to the caller.

    Time is measured in 1 / ``fps``: with the clip's fps the value is in SI units (about 9 for
    real HumanML3D motion); ``fps=1`` measures time in frames and gives exactly 3·ln(fps) less,
    about 0.2–1 for real motion — the magnitudes of the paper's tables (1.19 for real motion,
    below 0 for SLERP), so the paper most likely differentiated per frame.

    Still joints (see ``dimensionless_jerk``) are left out of a window's average, and a
    window in which no joint moves is left out; if nothing moves in any window the jerk is
    undefined and NaN is returned. A moving joint whose finite-difference jerk is exactly zero
    (e.g. constant velocity in exact arithmetic) gives −inf, the limit of perfect smoothness;
    round-off keeps real, generated and most procedural motion finite.
    """
    joints = _as_array(joints, "joints", 3)
    per_window = []
    for frames in transition_windows(joints, boundaries, window):
        if len(frames) < 4:
            raise ValueError(
                f"the window around a boundary keeps only {len(frames)} frames after "
                "clipping; the jerk needs at least 4 (use a larger window)"
            )
        ratios = dimensionless_jerk(frames, fps, min_step)
        if not np.isnan(ratios).all():
            with np.errstate(divide="ignore"):
                per_window.append(np.nanmean(np.log(ratios)))
    return float(np.mean(per_window)) if per_window else float("nan")


def frame_jerk(joints) -> np.ndarray:
    """FlowMDM's jerk curve of a clip of joint positions (F, J, 3): per frame, the third finite
    difference of each joint's position with Δt = 1 frame, its L1 norm over x, y, z, and the
    maximum over joints; F − 3 values, in the positions' unit per frame³. As Barquero et al.
    (CVPR 2024) compute it (BarqueroGerman/FlowMDM, ``data_loaders/humanml/utils/metrics.py``,
    ``calculate_jerk``); the curve behind Peak Jerk and AUJ (:func:`peak_jerk_and_auj`), not the
    paper's eq. 10 (:func:`jerk`) — the two are different metrics, never interchangeable."""
    joints = _as_array(joints, "joints", 3)
    if joints.shape[2] != 3:
        raise ValueError(f"joints must be (frames, joints, 3), got shape {joints.shape}")
    if len(joints) < 4:
        raise ValueError(f"a third difference needs at least 4 frames, got {len(joints)}")
    return np.abs(np.diff(joints, n=3, axis=0)).sum(-1).max(-1)


def mean_frame_jerk(clips: Sequence) -> float:
    """A dataset's mean of :func:`frame_jerk` over every frame of its clips (F − 3 each): the
    constant AUJ measures against (FlowMDM's 0.033031363 for HumanML3D, in metres)."""
    curves = [frame_jerk(clip) for clip in clips]
    if not curves:
        raise ValueError("mean_frame_jerk needs at least one clip")
    return float(np.concatenate(curves).mean())


def peak_jerk_and_auj(curves, reference: float) -> tuple[float, float]:
    """FlowMDM's Peak Jerk and Area Under the Jerk of a test set's transitions, from the
    :func:`frame_jerk` curves (n, L) of its equally long transition windows: the curves are
    averaged over the windows, PJ is that mean curve's maximum and AUJ is Σ over its frames of
    |mean − ``reference``|, with ``reference`` the dataset's :func:`mean_frame_jerk`."""
    curves = _as_array(curves, "curves", 2)
    if len(curves) == 0:
        raise ValueError("peak_jerk_and_auj needs at least one transition's curve")
    mean = curves.mean(0)
    return float(mean.max()), float(np.abs(mean - reference).sum())


def student_t_quantile(confidence: float, dof: int) -> float:
    """The t with P(|T| < t) = ``confidence`` for Student's T with ``dof`` degrees of freedom:
    the factor of a two-sided interval from ``dof + 1`` repeats (12.706 for 2 repeats at 95 %,
    1.96 as the repeats grow). P(|T| < t) is the closed form for integer degrees of freedom
    (Abramowitz & Stegun, Handbook of Mathematical Functions, 26.7.3 and 26.7.4), inverted by
    bisection: no statistics package needed."""
    if dof < 1 or not 0.0 < confidence < 1.0:
        raise ValueError(f"a t quantile needs dof >= 1 and 0 < confidence < 1, got {dof} and {confidence}")
    low, high = 0.0, 1.0
    while _t_central_mass(high, dof) < confidence:
        high *= 2.0
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if _t_central_mass(middle, dof) < confidence else (low, middle)
    return 0.5 * (low + high)


def _t_central_mass(t: float, dof: int) -> float:
    """P(|T| < t), A(t | ν) of Abramowitz & Stegun 26.7.3 (ν odd) and 26.7.4 (ν even), with
    θ = atan(t / √ν): a finite series in cos θ."""
    theta = np.arctan(t / np.sqrt(dof))
    cos2 = np.cos(theta) ** 2
    term, series = 1.0, 1.0
    # odd ν: 1 + 2/3 cos² + (2·4)/(3·5) cos⁴ + ... up to cos^(ν−3); even ν: 1 + 1/2 cos² + (1·3)/(2·4) cos⁴ + ...
    for k in range(1, (dof - 1) // 2 if dof % 2 else dof // 2):
        step = 2 * k if dof % 2 else 2 * k - 1
        term *= cos2 * step / (step + 1)
        series += term
    if dof % 2 == 0:
        return float(np.sin(theta) * series)
    if dof == 1:
        return float(2.0 * theta / np.pi)
    return float(2.0 / np.pi * (theta + np.sin(theta) * np.cos(theta) * series))


def mean_confidence_interval(values) -> tuple[float | np.ndarray, float | np.ndarray]:
    """Mean and 95 % half-width ``t · s / √n`` over n replications (axis 0): Student's t with
    n − 1 degrees of freedom and the sample standard deviation s (ddof 1), so that the interval
    holds at the few repeats an evaluation affords (at n = 2 it is 9.2 times Guo et al.'s
    ``1.96 · np.std / √n``, which assumes many). NaN half-widths from one replication, whose
    spread says nothing. Floats for a 1-D input; arrays for e.g. (n, top_k) R-precisions."""
    values = _as_array(values, "values")
    if values.ndim == 0 or len(values) == 0:
        raise ValueError(f"values must hold at least one replication along axis 0, got shape {values.shape}")
    mean = values.mean(0)
    if len(values) == 1:
        half_width = np.full_like(mean, np.nan)
    else:
        factor = student_t_quantile(CONFIDENCE, len(values) - 1)
        half_width = factor * values.std(0, ddof=1) / np.sqrt(len(values))
    if mean.ndim == 0:
        return float(mean), float(half_width)
    return mean, half_width
