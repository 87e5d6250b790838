"""Procedural human motion on the T2M skeleton, for the synthetic motion-language corpus.

A motion is first written as a :class:`Program`: per-frame curves for the pelvis (position,
heading, tilt), the spine, the neck, wrist targets for the arms (in the chest's frame), and ankle
targets plus foot orientation for the legs. :func:`render` turns a program into joint positions
with forward kinematics of the pelvis, spine, neck and collars on the standard hierarchy whose rest
offsets are ``T2M.raw_offsets × bone lengths`` (each joint's rotation moves all its child bones, so
the pelvis and the chest are rigid), and analytic two-bone IK for the limbs. That keeps every bone
at its length, bends knees and elbows only the anatomical way, and keeps a planted foot exactly
where it was put: its ankle target does not move, and the pelvis is lowered wherever a leg would
otherwise not reach.

Each action family is a function of the body, the :class:`State` the previous action left (where
the feet are, which way the body faces, standing or seated) and its parameters, and returns its
program and the state it ends in, so actions chain without jumps. Locomotion is driven by
footsteps: feet are planted, rolled over the toes and swung to the next footprint; the pelvis
follows the smoothed middle of the feet, so stride length × cadence is the speed.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from functools import cached_property
from typing import Callable, Sequence

import numpy as np

from m2d2m.motion.rotations import dot, euler_to_matrix, normalize
from m2d2m.motion.skeleton import T2M
from m2d2m.motion.smoothing import gaussian_smooth

FPS = T2M.fps
GRAVITY = 9.81
SIDES = ("left", "right")
LEFT, RIGHT = 0, 1

_SIGN = np.array([1.0, -1.0])  # body-frame x of the left and the right side: +x is the left
_UP = np.array([0.0, 1.0, 0.0])
_HIP, _KNEE, _ANKLE, _TOE = (1, 2), (4, 5), (7, 8), (10, 11)
_COLLAR, _SHOULDER, _ELBOW, _WRIST = (13, 14), (16, 17), (18, 19), (20, 21)
_SPINE = ((3, 0.3), (6, 0.35), (9, 0.35))  # spine joints and their share of the trunk angles
_TOE_HEIGHT = 0.012  # toe joint centre above the floor when the foot is down (m)
_FOOT_PITCH = np.radians(22.0)  # ankle→toe bone below the horizontal when the foot is flat
_NECK_REST = -1.2  # raw neck→head offset is +z; this tips it up and a little forward
_COLLAR_REST = np.radians(160.0)  # raw collar→shoulder offset is −y; this points it up and out
_LIFT_PITCH = 0.75  # extra toes-down pitch of a foot pushing off or landing on its toes
_REACH = 0.998  # legs never straighter than this fraction of thigh + shin
_BONE_GROUPS = {
    "legs": (4, 5, 7, 8, 10, 11),
    "arms": (16, 17, 18, 19, 20, 21),
    "torso": (3, 6, 9, 12, 15),
    "hips": (1, 2),
    "collars": (13, 14),
}


# --------------------------------------------------------------------------- small maths


def _ease(u: np.ndarray | float) -> np.ndarray:
    """Quintic smoothstep: 0→1 with zero velocity and acceleration at both ends."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (u * (6.0 * u - 15.0) + 10.0)


def _keys(frames: int, keys: Sequence[tuple[float, object]]) -> np.ndarray:
    """Curve (frames, ...) through ``(frame, value)`` keys, eased between consecutive keys and held
    before the first and after the last; the way an animator blocks a pose-to-pose motion."""
    t = np.arange(frames, dtype=np.float64)
    values = np.array([np.asarray(v, dtype=np.float64) for _, v in keys])
    out = np.empty((frames,) + values.shape[1:])
    out[:] = values[0]
    shape = (-1,) + (1,) * (values.ndim - 1)
    for (t0, v0), (t1, v1) in zip(keys[:-1], keys[1:]):
        after = t >= t0
        w = _ease((t[after] - t0) / max(t1 - t0, 1e-9)).reshape(shape)
        out[after] = np.asarray(v0) + (np.asarray(v1) - np.asarray(v0)) * w
    return out


def _smooth_cover(x: np.ndarray, radius: int) -> np.ndarray:
    """A smooth curve that is never below ``x``: a running maximum, then an average over a window
    no wider than the maximum's, so every averaged value is ≥ the original at the centre."""
    padded = np.pad(x, radius, mode="edge")
    dilated = np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1).max(axis=-1)
    padded = np.pad(dilated, radius, mode="edge")
    kernel = np.hanning(2 * radius + 3)[1:-1]
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1) @ (kernel / kernel.sum())


def _forward(yaw: np.ndarray | float) -> np.ndarray:
    """Horizontal unit vector a body with heading ``yaw`` faces (yaw 0 faces +z, +yaw turns left)."""
    yaw = np.asarray(yaw, dtype=np.float64)
    return np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=-1)


def _leftward(yaw: np.ndarray | float) -> np.ndarray:
    """Horizontal unit vector to the body's left."""
    yaw = np.asarray(yaw, dtype=np.float64)
    return np.stack([np.cos(yaw), np.zeros_like(yaw), -np.sin(yaw)], axis=-1)


def _to_world(yaw: np.ndarray | float, local: np.ndarray) -> np.ndarray:
    """Body-frame vectors (x left, y up, z forward) to world vectors for heading ``yaw``."""
    local = np.asarray(local, dtype=np.float64)
    return (
        local[..., 0:1] * _leftward(yaw) + local[..., 1:2] * _UP + local[..., 2:3] * _forward(yaw)
    )


def _foot_direction(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Unit ankle→toe direction of a foot turned to ``yaw`` and pitched ``pitch`` toes-down."""
    return np.cos(pitch)[..., None] * _forward(yaw) - np.sin(pitch)[..., None] * _UP


def _two_bone(
    root: np.ndarray, target: np.ndarray, pole: np.ndarray, upper: float, lower: float
) -> tuple[np.ndarray, np.ndarray]:
    """Analytic two-bone IK: middle joint and end positions (T, 3) reaching for ``target`` with
    the middle joint pushed toward ``pole``; targets out of reach are approached along the line."""
    delta = target - root
    distance = np.sqrt(dot(delta, delta))
    axis = delta / np.maximum(distance, 1e-9)[:, None]
    reach = np.clip(distance, abs(upper - lower) + 1e-3, (upper + lower) * (1.0 - 1e-4))
    cos_a = (upper**2 + reach**2 - lower**2) / (2.0 * upper * reach)
    sin_a = np.sqrt(np.clip(1.0 - cos_a**2, 0.0, 1.0))
    side = normalize(pole - dot(pole, axis)[:, None] * axis)
    middle = root + upper * (cos_a[:, None] * axis + sin_a[:, None] * side)
    return middle, root + reach[:, None] * axis


# --------------------------------------------------------------------------- the body


def _symmetric_lengths() -> np.ndarray:
    """T2M's target bone lengths with each left/right pair replaced by its mean."""
    lengths = T2M.bone_lengths.copy()
    for left, right in zip(T2M.left_joints, T2M.right_joints):
        lengths[left] = lengths[right] = 0.5 * (lengths[left] + lengths[right])
    return lengths


@dataclass(frozen=True)
class Body:
    """One synthetic person: bone lengths (m) and a few traits of how they move."""

    lengths: np.ndarray
    scale: float
    toe_out: float  # each foot turned out from the heading (rad)
    step_width: float  # lateral distance between the ankles when standing (m)
    energy: float  # multiplier of arm swing and gesture amplitudes
    tempo: float  # multiplier of cadences

    @cached_property
    def offsets(self) -> np.ndarray:
        """Rest offsets (22, 3): T2M's raw directions times this body's lengths."""
        return T2M.raw_offsets * self.lengths[:, None]

    @property
    def thigh(self) -> float:
        return float(self.lengths[_KNEE[0]])

    @property
    def shin(self) -> float:
        return float(self.lengths[_ANKLE[0]])

    @property
    def foot(self) -> float:
        return float(self.lengths[_TOE[0]])

    @property
    def upper_arm(self) -> float:
        return float(self.lengths[_ELBOW[0]])

    @property
    def forearm(self) -> float:
        return float(self.lengths[_WRIST[0]])

    @property
    def leg(self) -> float:
        return self.thigh + self.shin

    @property
    def arm(self) -> float:
        return self.upper_arm + self.forearm

    @property
    def ankle_height(self) -> float:
        """Ankle joint height when the foot is flat on the floor."""
        return _TOE_HEIGHT + self.foot * float(np.sin(_FOOT_PITCH))

    @property
    def stand_height(self) -> float:
        """Pelvis height when standing with the knees almost straight."""
        return self.ankle_height + 0.994 * self.leg

    @property
    def shoulder_half_width(self) -> float:
        """Lateral distance of a shoulder joint from the chest's midline."""
        return float(self.lengths[_COLLAR[0]] + self.lengths[_SHOULDER[0]] * np.sin(_COLLAR_REST))


def sample_body(rng: np.random.Generator) -> Body:
    """A person of random size (overall ×0.85–1.15, each body part ±6 %, left = right)."""
    scale = float(np.clip(rng.normal(1.0, 0.07), 0.85, 1.15))
    lengths = _symmetric_lengths() * scale
    for joints in _BONE_GROUPS.values():
        lengths[list(joints)] *= np.clip(rng.normal(1.0, 0.025), 0.94, 1.06)
    return Body(
        lengths=lengths,
        scale=scale,
        toe_out=float(rng.uniform(0.04, 0.16)),
        step_width=float(rng.uniform(0.15, 0.22) * scale),
        energy=float(rng.uniform(0.8, 1.2)),
        tempo=float(rng.uniform(0.93, 1.07)),
    )


# --------------------------------------------------------------------------- programs


@dataclass
class Program:
    """Per-frame curves that describe a motion; all arrays have the frame count first."""

    pelvis: np.ndarray  # (T, 3) world position; y is the wished height before the leg-reach fit
    yaw: np.ndarray  # (T,) heading of the pelvis
    tilt: np.ndarray  # (T, 2) pelvis pitch (forward) and roll (toward the left)
    trunk: np.ndarray  # (T, 3) spine flexion, bend toward the left, twist toward the left
    neck: np.ndarray  # (T, 2) head nod (down) and turn (left)
    wrists: np.ndarray  # (T, 2, 3) each wrist relative to its shoulder, in the chest frame
    elbows: np.ndarray  # (T, 2, 3) direction each elbow points, in the chest frame
    ankles: np.ndarray  # (T, 2, 3) world ankle targets
    foot_yaw: np.ndarray  # (T, 2)
    foot_pitch: np.ndarray  # (T, 2) toes-down angle of the ankle→toe bone

    def __len__(self) -> int:
        return len(self.yaw)

    @staticmethod
    def concat(programs: Sequence[Program]) -> Program:
        return Program(
            **{f.name: np.concatenate([getattr(p, f.name) for p in programs]) for f in fields(Program)}
        )


# Channels that are cross-faded between actions; the rest are continuous by construction.
_BLENDED = ("tilt", "trunk", "neck", "wrists", "elbows")


def blend_boundaries(program: Program, boundaries: Sequence[int], frames: int = 8) -> Program:
    """Fade out any jump of the posture channels at each boundary over ``frames`` (0.4 s):
    the new action starts from the previous pose and converges to its own curve."""
    program = replace(program, **{name: getattr(program, name).copy() for name in _BLENDED})
    weights = 1.0 - _ease((np.arange(frames) + 1.0) / (frames + 1.0))
    for b in boundaries:
        if not 0 < b < len(program):
            continue
        span = min(frames, len(program) - b)
        for name in _BLENDED:
            x = getattr(program, name)
            jump = x[b - 1] - x[b]
            x[b : b + span] += jump[None] * weights[:span].reshape((-1,) + (1,) * jump.ndim)
    return program


@dataclass(frozen=True)
class State:
    """Where an action leaves the body: feet (planted), heading and posture."""

    ankles: np.ndarray  # (2, 3)
    foot_yaw: np.ndarray  # (2,)
    yaw: float
    seated: bool = False

    @property
    def centre(self) -> np.ndarray:
        """Floor point between the feet."""
        centre = self.ankles.mean(axis=0)
        centre[1] = 0.0
        return centre


def initial_state(body: Body, rng: np.random.Generator, seated: bool = False) -> State:
    """Feet side by side at a random place and heading (raw corpora are not canonicalised)."""
    yaw = float(rng.uniform(-np.pi, np.pi))
    centre = np.array([rng.uniform(-1.0, 1.0), 0.0, rng.uniform(-1.0, 1.0)])
    return _feet_at(body, centre, yaw, seated)


def _feet_at(body: Body, centre: np.ndarray, yaw: float, seated: bool = False) -> State:
    """Standing (or seated) state with both feet at the body's width around ``centre``."""
    ankles = centre[None] + _SIGN[:, None] * 0.5 * body.step_width * _leftward(yaw)[None]
    ankles[:, 1] = body.ankle_height
    return State(ankles, yaw + _SIGN * body.toe_out, float(yaw), seated)


def arm_pose(
    body: Body, side: int, flex: np.ndarray | float, abduct: np.ndarray | float,
    elbow: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray]:
    """Wrist target and elbow pole (chest frame) of an arm swung forward by ``flex``, out by
    ``abduct`` and bent forward at the elbow by ``elbow`` (radians, any broadcastable shapes)."""
    flex, abduct, elbow = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (flex, abduct, elbow))
    )
    s = _SIGN[side]
    upper = np.stack(
        [s * np.sin(abduct), -np.cos(abduct) * np.cos(flex), np.cos(abduct) * np.sin(flex)], axis=-1
    )
    ahead = np.stack([np.zeros_like(flex), np.sin(flex), np.cos(flex)], axis=-1)
    ahead = normalize(ahead - dot(ahead, upper)[..., None] * upper)
    lower = np.cos(elbow)[..., None] * upper + np.sin(elbow)[..., None] * ahead
    wrist = body.upper_arm * upper + body.forearm * lower
    pole = -ahead + np.array([0.3 * s, 0.0, 0.0])
    return wrist, pole


def _rest_arms(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Relaxed arms hanging by the sides: wrist targets and elbow poles (2, 3)."""
    arms = [arm_pose(body, side, 0.06, 0.12, 0.3) for side in (LEFT, RIGHT)]
    return np.stack([a[0] for a in arms]), np.stack([a[1] for a in arms])


def _seated_pelvis(body: Body, state: State) -> np.ndarray:
    """Pelvis on an implied seat: thighs level, shins about vertical."""
    back = 0.9 * body.thigh
    return state.centre - back * _forward(state.yaw) + _UP * (body.ankle_height + 0.97 * body.shin)


def _hold(body: Body, state: State, frames: int) -> Program:
    """Still standing (or seated) pose, the base every other program edits."""
    wrists, elbows = _rest_arms(body)
    if state.seated:
        pelvis = _seated_pelvis(body, state)
        tilt, trunk = (-0.12, 0.0), (0.22, 0.0, 0.0)
        for side in (LEFT, RIGHT):
            wrists[side] = np.array([-0.02 * _SIGN[side], -0.62, 0.55]) * body.arm
            elbows[side] = np.array([0.5 * _SIGN[side], 0.0, -1.0])
    else:
        pelvis = state.centre + _UP * body.stand_height
        tilt, trunk = (0.06, 0.0), (0.0, 0.0, 0.0)

    def constant(value: object) -> np.ndarray:
        value = np.asarray(value, dtype=np.float64)
        return np.repeat(value[None], frames, axis=0)

    return Program(
        pelvis=constant(pelvis),
        yaw=constant(state.yaw),
        tilt=constant(tilt),
        trunk=constant(trunk),
        neck=constant((0.0, 0.0)),
        wrists=constant(wrists),
        elbows=constant(elbows),
        ankles=constant(state.ankles),
        foot_yaw=constant(state.foot_yaw),
        foot_pitch=constant((_FOOT_PITCH, _FOOT_PITCH)),
    )


def idle(body: Body, state: State, frames: int, rng: np.random.Generator) -> Program:
    """Standing or sitting still, with a slow weight shift and breathing so nothing is frozen."""
    program = _hold(body, state, frames)
    t = np.arange(frames) / FPS
    phase = rng.uniform(0, 2 * np.pi, size=3)
    shift = 0.008 * np.sin(2 * np.pi * t / 3.1 + phase[0])
    if not state.seated:
        program.pelvis += shift[:, None] * _leftward(state.yaw)[None]
        program.tilt[:, 1] -= 1.5 * shift
    program.trunk[:, 0] += 0.015 * np.sin(2 * np.pi * t / 3.7 + phase[1])
    program.neck[:, 1] += 0.06 * np.sin(2 * np.pi * t / 4.3 + phase[2])
    return program


# --------------------------------------------------------------------------- texture


@dataclass(frozen=True)
class Texture:
    """How much high-frequency content real capture adds on top of the animated curves: the RMS
    second difference (per frame², 20 fps) of band-limited noise on the pelvis position (m), the
    trunk, pelvis tilt and neck angles (rad) and the wrist targets (m). Real motion is never as
    smooth as eased keys; its acceleration spectrum stays flat up to the Nyquist rate, and both
    the paper's Jerk (eq. 10) and FlowMDM's PJ/AUJ are dominated by that band. The defaults are
    calibrated against real HumanML3D motion (``bench/calibrate_corpus.py``, docs/data.md)."""

    pelvis: float = 0.0
    angles: float = 0.0
    wrists: float = 0.0
    low_hz: float = 3.0  # the band starts here: what a viewer would call the motion is below

    def apply(self, program: Program, rng: np.random.Generator) -> Program:
        """The program with independent band-limited noise added to each textured channel."""
        frames = len(program)
        changes = {
            "pelvis": (program.pelvis, self.pelvis),
            "tilt": (program.tilt, self.angles),
            "trunk": (program.trunk, self.angles),
            "neck": (program.neck, self.angles),
            "wrists": (program.wrists, self.wrists),
        }
        return replace(program, **{
            name: curve + level * band_noise(frames, curve.shape[1:], rng, self.low_hz)
            for name, (curve, level) in changes.items()
        })


def band_noise(frames: int, shape: tuple[int, ...], rng: np.random.Generator,
               low_hz: float, fps: float = FPS) -> np.ndarray:
    """Gaussian noise (frames, *shape) whose second difference has a flat spectrum above
    ``low_hz`` (a raised-cosine edge from half of it), nothing below, and unit RMS: positions
    from white acceleration in one band, made in the frequency domain over twice the length so
    the circular wrap never shows."""
    n = 2 * frames + 8
    freqs = np.fft.rfftfreq(n, 1.0 / fps)
    edge = np.clip((freqs - 0.5 * low_hz) / (0.5 * low_hz), 0.0, 1.0)
    gain = 0.5 - 0.5 * np.cos(np.pi * edge)
    second_difference = 4.0 * np.sin(np.pi * freqs / fps) ** 2  # |H| of x[t+1] − 2x[t] + x[t−1]
    transfer = np.divide(gain, second_difference, out=np.zeros_like(gain), where=gain > 0)
    spectrum = rng.standard_normal((len(freqs),) + shape) + 1j * rng.standard_normal((len(freqs),) + shape)
    x = np.fft.irfft(spectrum * transfer.reshape((-1,) + (1,) * len(shape)), n=n, axis=0)[:frames]
    rms = np.sqrt(np.mean(np.diff(x, n=2, axis=0) ** 2)) if frames > 2 else 1.0
    return x / max(rms, 1e-12)


# --------------------------------------------------------------------------- rendering


def _rot(angles: np.ndarray) -> np.ndarray:
    """Rotation matrices of (yaw-like twist about y, flexion about x, bend about −z) angles."""
    return euler_to_matrix(angles, "YXZ")


def _fit_pelvis_height(pelvis: np.ndarray, r0: np.ndarray, ankles: np.ndarray, body: Body) -> np.ndarray:
    """Lower the wished pelvis height, smoothly, wherever a leg could not reach its ankle target;
    elsewhere the wished curve (a jump's parabola, say) is kept as it is."""
    reach = _REACH * body.leg
    highest = np.full(len(pelvis), np.inf)
    for side in (LEFT, RIGHT):
        hip = pelvis + r0 @ body.offsets[_HIP[side]]
        horizontal = (hip[:, 0] - ankles[:, side, 0]) ** 2 + (hip[:, 2] - ankles[:, side, 2]) ** 2
        vertical = np.sqrt(np.maximum(reach**2 - horizontal, 0.0))
        highest = np.minimum(highest, ankles[:, side, 1] + vertical - (hip[:, 1] - pelvis[:, 1]))
    fitted = pelvis.copy()
    fitted[:, 1] -= _smooth_cover(np.maximum(pelvis[:, 1] - highest, 0.0), 3)
    return fitted


def program_joints(program: Program, body: Body) -> np.ndarray:
    """Joint positions (T, 22, 3) of a program: FK for the pelvis, spine, neck and collars, two-bone
    IK for the arms (wrist targets in the chest frame) and the legs (world ankle targets)."""
    frames = len(program)
    offsets = body.offsets
    joints = np.empty((frames, T2M.num_joints, 3))
    r0 = _rot(np.stack([program.yaw, program.tilt[:, 0], -program.tilt[:, 1]], axis=-1))
    joints[:, 0] = _fit_pelvis_height(program.pelvis, r0, program.ankles, body)
    for joint in (1, 2, 3):
        joints[:, joint] = joints[:, 0] + r0 @ offsets[joint]

    trunk = program.trunk
    rot = r0
    for joint, share in _SPINE:
        rot = rot @ _rot(share * np.stack([trunk[:, 2], trunk[:, 0], -trunk[:, 1]], axis=-1))
        child = {3: 6, 6: 9, 9: 12}[joint]
        joints[:, child] = joints[:, joint] + rot @ offsets[child]
    chest = rot
    neck = chest @ _rot(np.stack([program.neck[:, 1], _NECK_REST + program.neck[:, 0],
                                  np.zeros(frames)], axis=-1))
    joints[:, 15] = joints[:, 12] + neck @ offsets[15]

    for side in (LEFT, RIGHT):
        collar, shoulder, elbow, wrist = _COLLAR[side], _SHOULDER[side], _ELBOW[side], _WRIST[side]
        joints[:, collar] = joints[:, 9] + chest @ offsets[collar]
        collar_rot = chest @ _rot(np.array([0.0, 0.0, _SIGN[side] * _COLLAR_REST]))
        joints[:, shoulder] = joints[:, collar] + collar_rot @ offsets[shoulder]
        target = joints[:, shoulder] + np.einsum("tij,tj->ti", chest, program.wrists[:, side])
        pole = np.einsum("tij,tj->ti", chest, program.elbows[:, side])
        joints[:, elbow], joints[:, wrist] = _two_bone(
            joints[:, shoulder], target, pole, body.upper_arm, body.forearm
        )

        hip, knee, ankle, toe = _HIP[side], _KNEE[side], _ANKLE[side], _TOE[side]
        knee_pole = _forward(0.5 * (program.foot_yaw[:, side] + program.yaw)) + 0.6 * _UP
        joints[:, knee], joints[:, ankle] = _two_bone(
            joints[:, hip], program.ankles[:, side], knee_pole, body.thigh, body.shin
        )
        joints[:, toe] = joints[:, ankle] + body.foot * _foot_direction(
            program.foot_yaw[:, side], program.foot_pitch[:, side]
        )
    return joints


# --------------------------------------------------------------------------- stepping


@dataclass(frozen=True)
class Step:
    """One footstep: which foot, when it leaves and touches the floor (frames), where it lands."""

    side: int
    lift: float
    land: float
    ankle: np.ndarray
    yaw: float


@dataclass(frozen=True)
class Gait:
    """How a kind of stepping looks; lengths in metres, angles in radians, times in seconds."""

    roll: float = 0.0  # heel-off (pivot on the toes) before lift-off; 0 = flat steps
    toe_off: float = 0.0  # extra toes-down pitch reached at lift-off
    land_pitch: float = 0.0  # pitch offset at touchdown (negative: toes up, heel first)
    settle: float = 0.1  # time for the foot to come flat after touchdown
    clearance: float = 0.06  # peak ankle lift in swing
    crouch: float = 0.0  # pelvis lowered while stepping
    bounce: float = 0.0  # extra pelvis drop while a foot is on the floor (running)
    lean: float = 0.02  # trunk flexion while stepping
    arm_swing: float = 0.0  # shoulder swing amplitude
    elbow: float = 0.3  # elbow flexion while stepping
    sway: float = 0.0  # lateral pelvis shift over the supporting foot
    twist: float = 0.0  # pelvis rotation about the vertical with the legs


WALK = Gait(roll=0.2, toe_off=0.8, land_pitch=-0.3, settle=0.12, clearance=0.07, crouch=0.02,
            lean=0.04, arm_swing=0.32, elbow=0.35, sway=0.025, twist=0.09)
JOG = Gait(roll=0.1, toe_off=0.7, land_pitch=-0.1, settle=0.06, clearance=0.13, crouch=0.05,
           bounce=0.035, lean=0.12, arm_swing=0.55, elbow=1.35, sway=0.012, twist=0.1)
RUN = Gait(roll=0.08, toe_off=0.75, land_pitch=0.0, settle=0.05, clearance=0.2, crouch=0.06,
           bounce=0.05, lean=0.2, arm_swing=0.75, elbow=1.5, sway=0.01, twist=0.12)
BACKWARD = Gait(clearance=0.06, crouch=0.02, lean=0.0, arm_swing=0.15, elbow=0.35, sway=0.02,
                twist=0.04)
SHUFFLE = Gait(clearance=0.05, crouch=0.03, lean=0.03, elbow=0.35, settle=0.05)


def _foot_tracks(
    body: Body, state: State, steps: Sequence[Step], frames: int, gait: Gait
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ankle targets (T, 2, 3), foot yaw and pitch (T, 2) and on-floor flags (T, 2) of footsteps:
    each foot stays planted, rolls over its toes, swings to its next footprint and settles flat."""
    t = np.arange(frames, dtype=np.float64)
    ankles = np.repeat(state.ankles[None], frames, axis=0)
    yaw = np.repeat(state.foot_yaw[None], frames, axis=0)
    pitch = np.full((frames, 2), _FOOT_PITCH)
    down = np.ones((frames, 2), dtype=bool)
    current = {side: (state.ankles[side], float(state.foot_yaw[side])) for side in (LEFT, RIGHT)}
    roll, settle = gait.roll * FPS, max(gait.settle * FPS, 1e-6)
    for step in sorted(steps, key=lambda s: s.lift):
        side = step.side
        start_ankle, start_yaw = current[side]
        toe = start_ankle + body.foot * _foot_direction(np.array(start_yaw), np.array(_FOOT_PITCH))
        off_pitch = _FOOT_PITCH + (gait.toe_off if roll > 0 else 0.0)

        rolling = (t >= step.lift - roll) & (t < step.lift)
        if roll > 0 and rolling.any():
            u = (t[rolling] - (step.lift - roll)) / roll
            p = _FOOT_PITCH + gait.toe_off * u**2
            ankles[rolling, side] = toe - body.foot * _foot_direction(np.full_like(p, start_yaw), p)
            pitch[rolling, side] = p
        off_ankle = toe - body.foot * _foot_direction(np.array(start_yaw), np.array(off_pitch))

        swinging = (t >= step.lift) & (t < step.land)
        u = (t[swinging] - step.lift) / (step.land - step.lift)
        s = _ease(u)[:, None]
        path = off_ankle + (step.ankle - off_ankle) * s
        path[:, 1] += gait.clearance * body.scale * np.sin(np.pi * u**0.8)
        ankles[swinging, side] = path
        yaw[swinging, side] = start_yaw + (step.yaw - start_yaw) * s[:, 0]
        pitch[swinging, side] = off_pitch + (_FOOT_PITCH + gait.land_pitch - off_pitch) * s[:, 0]
        down[swinging, side] = False

        landed = t >= step.land
        ankles[landed, side] = step.ankle
        yaw[landed, side] = step.yaw
        pitch[landed, side] = _FOOT_PITCH + gait.land_pitch * (
            1.0 - _ease((t[landed] - step.land) / settle)
        )
        current[side] = (step.ankle, step.yaw)
    return ankles, yaw, pitch, down


def _stepping(
    body: Body, state: State, steps: Sequence[Step], gait: Gait, period: float, *,
    end_yaw: float | None = None, seconds_after: float = 0.45,
) -> tuple[Program, State]:
    """Program of a footstep sequence: feet from :func:`_foot_tracks`, the pelvis at the smoothed
    middle of the feet (so stride × cadence is its speed) with sway over the supporting foot,
    counter-rotating pelvis and chest, and arms swinging opposite to the legs."""
    last = max(s.land for s in steps) + gait.settle * FPS
    frames = int(np.ceil(last + seconds_after * FPS))
    ankles, foot_yaw, foot_pitch, down = _foot_tracks(body, state, steps, frames, gait)
    program = _hold(body, state, frames)
    t = np.arange(frames, dtype=np.float64)
    sigma = 0.3 * period * FPS

    first = min(s.lift for s in steps) - gait.roll * FPS - 2.0
    moving = gaussian_smooth(((t >= first) & (t <= last)).astype(np.float64), sigma, truncate=3.0)
    moving *= _ease(t / 6.0) * _ease((frames - 1.0 - t) / 6.0)  # at rest at both ends
    yaw = gaussian_smooth(foot_yaw.mean(axis=1), sigma, truncate=3.0)
    centre = gaussian_smooth(ankles.mean(axis=1), sigma, truncate=3.0)
    centre[:, 1] = 0.0
    final_yaw = float(foot_yaw[-1].mean()) if end_yaw is None else end_yaw
    end = State(ankles[-1].copy(), foot_yaw[-1].copy(), final_yaw, False)
    centre = _pin_end(centre, end.centre)
    yaw = _pin_end(yaw, final_yaw)

    support = gaussian_smooth(down[:, LEFT].astype(float) - down[:, RIGHT].astype(float), sigma, truncate=3.0)
    separation = dot(ankles[:, LEFT] - ankles[:, RIGHT], _forward(yaw))
    stride = max(float(np.percentile(np.abs(separation), 95)), 0.25)
    ahead = np.clip(gaussian_smooth(separation, 1.0, truncate=3.0) / stride, -1.0, 1.0)  # +1: left foot ahead
    airborne = gaussian_smooth((~down.any(axis=1)).astype(np.float64), 1.0, truncate=3.0)
    on_floor = gaussian_smooth(down.any(axis=1).astype(np.float64) * moving, 1.0, truncate=3.0)

    program.pelvis = centre + _UP * body.stand_height
    program.pelvis += (gait.sway * body.scale * support)[:, None] * _leftward(yaw)
    program.pelvis[:, 1] -= (gait.crouch * moving + gait.bounce * on_floor) * body.scale
    program.pelvis[:, 1] += 0.3 * gait.bounce * airborne * body.scale
    program.yaw = yaw - gait.twist * ahead
    program.tilt[:, 0] += 0.5 * gait.lean * moving
    program.tilt[:, 1] -= 2.0 * gait.sway * support  # the hip of the swinging leg drops
    program.trunk[:, 0] += gait.lean * moving
    program.trunk[:, 2] += 1.8 * gait.twist * ahead
    program.neck[:, 0] -= 0.8 * gait.lean * moving
    program.neck[:, 1] -= 0.8 * gait.twist * ahead
    for side in (LEFT, RIGHT):
        swing = -_SIGN[side] * gait.arm_swing * body.energy * ahead
        elbow = 0.3 + (gait.elbow - 0.3) * moving + 0.35 * np.maximum(swing, 0.0)
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + swing, 0.12 + 0.06 * moving, elbow
        )
    program.ankles, program.foot_yaw, program.foot_pitch = ankles, foot_yaw, foot_pitch
    return program, end


def _pin_end(x: np.ndarray, target: np.ndarray | float, frames: int = 8) -> np.ndarray:
    """Bend the last ``frames`` of a curve so it ends exactly on ``target``."""
    x = np.array(x, dtype=np.float64)
    frames = min(frames, len(x))
    w = _ease(np.linspace(0.0, 1.0, frames)).reshape((-1,) + (1,) * (x.ndim - 1))
    x[-frames:] += (np.asarray(target) - x[-1]) * w
    return x


Path = Callable[[float], tuple[np.ndarray, float]]


def _straight(state: State, direction: float) -> Path:
    """Straight line from the feet's centre; ``direction`` relative to the heading."""
    heading = state.yaw + direction
    start, towards = state.centre, _forward(heading)
    return lambda s: (start + towards * s, heading)


def _circle(state: State, radius: float, turn: float) -> Path:
    """Circle of ``radius`` starting at the feet's centre, curving left (``turn`` +1,
    counterclockwise seen from above) or right (−1, clockwise)."""
    centre = state.centre + turn * radius * _leftward(state.yaw)

    def path(s: float) -> tuple[np.ndarray, float]:
        heading = state.yaw + turn * s / radius
        return centre - turn * radius * _leftward(heading), heading

    return path


def _path_steps(
    body: Body, path: Path, advances: Sequence[float], period: float, swing: float,
    gait: Gait, first_side: int, facing: float = 0.0,
) -> list[Step]:
    """Footsteps along ``path``: step i lands ``sum(advances[:i])`` along it (the last step closes
    beside the previous one), alternating feet every ``period`` seconds, each airborne for
    ``swing`` periods, feet turned to the path heading plus ``facing``."""
    steps = []
    lead = (0.2 + gait.roll) * FPS
    distance = np.concatenate([[0.0], np.cumsum(advances)])
    count = len(advances) + 1
    for i in range(count):
        side = first_side if i % 2 == 0 else 1 - first_side
        where, heading = path(float(distance[min(i + 1, count - 1)]))
        face = heading + facing
        ankle = where + _SIGN[side] * 0.5 * body.step_width * _leftward(face)
        ankle[1] = body.ankle_height
        lift = lead + i * period * FPS
        steps.append(Step(side, lift, lift + swing * period * FPS, ankle, face + _SIGN[side] * body.toe_out))
    return steps


def _ramp(count: int, length: float, ramp: Sequence[float]) -> list[float]:
    """Step advances: full ``length`` in the middle, shorter while speeding up and slowing down."""
    advances = [length] * count
    for i, factor in enumerate(ramp):
        if i < count:
            advances[i] = min(advances[i], factor * length)
            advances[-1 - i] = min(advances[-1 - i], factor * length)
    return advances


# --------------------------------------------------------------------------- locomotion families

_WALK_SPEEDS = {"slow": (0.40, 1.55), "normal": (0.52, 1.8), "fast": (0.62, 2.05)}  # step m, steps/s
_JOG_SPEEDS = {"slow": (0.75, 2.4), "normal": (0.9, 2.6)}
_RUN_SPEEDS = {"normal": (1.0, 3.0), "fast": (1.15, 3.2)}


def _stride(body: Body, table: dict, speed: str, rng: np.random.Generator) -> tuple[float, float]:
    """Step length (scaled by leg length) and period (s) for a speed word, with a little jitter."""
    length, cadence = table[speed]
    length *= body.leg / 0.826 * rng.uniform(0.95, 1.05)
    return length, 1.0 / (cadence * body.tempo * rng.uniform(0.97, 1.03))


def walk(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``steps`` footsteps forward at a ``speed`` (slow / normal / fast)."""
    length, period = _stride(body, _WALK_SPEEDS, p["speed"], rng)
    steps = _path_steps(body, _straight(state, 0.0), [length] * (p["steps"] - 1), period, 0.8,
                        WALK, int(rng.integers(2)))
    return _stepping(body, state, steps, WALK, period)


def walk_backwards(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``steps`` flat-footed steps backwards, still facing forward."""
    length, period = _stride(body, {"slow": (0.28, 1.4), "normal": (0.36, 1.65)}, p["speed"], rng)
    steps = _path_steps(body, _straight(state, np.pi), [length] * (p["steps"] - 1), period, 0.7,
                        BACKWARD, int(rng.integers(2)), facing=-np.pi)
    return _stepping(body, state, steps, BACKWARD, period)


def walk_circle(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """One full circle of ``radius`` m, ``clockwise`` or counterclockwise seen from above."""
    turn = -1.0 if p["direction"] == "clockwise" else 1.0
    length, period = _stride(body, {"normal": (0.46, 1.8)}, "normal", rng)
    count = max(int(round(2 * np.pi * p["radius"] / length)), 6)
    length = 2 * np.pi * p["radius"] / count
    steps = _path_steps(body, _circle(state, p["radius"], turn), [length] * count, period, 0.8,
                        WALK, int(turn < 0))
    return _stepping(body, state, steps, WALK, period)


def jog(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Jogging forward for ``steps`` footsteps, speeding up and slowing down."""
    length, period = _stride(body, _JOG_SPEEDS, p["speed"], rng)
    advances = _ramp(p["steps"] - 1, length, (0.45, 0.75, 0.92))
    steps = _path_steps(body, _straight(state, 0.0), advances, period, 1.25, JOG, int(rng.integers(2)))
    return _stepping(body, state, steps, JOG, period)


def run(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Running forward for ``steps`` footsteps, speeding up and slowing down."""
    length, period = _stride(body, _RUN_SPEEDS, p["speed"], rng)
    advances = _ramp(p["steps"] - 1, length, (0.4, 0.65, 0.85, 0.95))
    steps = _path_steps(body, _straight(state, 0.0), advances, period, 1.4, RUN, int(rng.integers(2)))
    return _stepping(body, state, steps, RUN, period)


def sidestep(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` step-together sidesteps toward ``side``: the leading foot opens, the other closes."""
    lead = SIDES.index(p["side"])
    width = rng.uniform(0.26, 0.36) * body.scale
    period = rng.uniform(0.42, 0.5) / body.tempo
    towards = _SIGN[lead] * _leftward(state.yaw)
    steps = []
    for k in range(p["count"]):
        for j, side in enumerate((lead, 1 - lead)):
            lift = (0.2 + (2 * k + j) * period) * FPS
            ankle = state.ankles[side] + towards * width * (k + 1)
            steps.append(Step(side, lift, lift + 0.65 * period * FPS, ankle, float(state.foot_yaw[side])))
    return _stepping(body, state, steps, SHUFFLE, 2 * period, end_yaw=state.yaw)


def turn(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Turning on the spot by ``angle`` degrees toward ``side`` in small pivoting steps, the foot on
    the turning side first; the head leads the turn."""
    sign = 1.0 if p["side"] == "left" else -1.0
    total = sign * np.radians(p["angle"])
    count = max(2, int(np.ceil(abs(p["angle"]) / 50.0)))
    period = rng.uniform(0.42, 0.52) / body.tempo
    centre = state.centre
    lead = LEFT if sign > 0 else RIGHT
    steps = []
    for i in range(count + 1):
        side = lead if i % 2 == 0 else 1 - lead
        heading = state.yaw + total * min(i + 1, count) / count
        ankle = centre + _SIGN[side] * 0.5 * body.step_width * _leftward(heading)
        ankle[1] = body.ankle_height
        lift = (0.2 + i * period) * FPS
        steps.append(Step(side, lift, lift + 0.7 * period * FPS, ankle, heading + _SIGN[side] * body.toe_out))
    program, end = _stepping(body, state, steps, SHUFFLE, 2 * period, end_yaw=state.yaw + total)
    look = _keys(len(program), [(0, 0.0), (steps[0].lift, 0.35 * sign), (steps[-1].land, 0.0)])
    program.neck[:, 1] += look
    return program, end


# --------------------------------------------------------------------------- leaps (jump, hop)


@dataclass(frozen=True)
class _Leap:
    """Vertical timing of one take-off and landing: a crouch, a push with constant upward
    acceleration, a ballistic flight, a landing that brakes with constant deceleration and a
    recovery, so the pelvis height and its velocity are continuous. Times are frames."""

    start: float
    crouch_end: float
    takeoff: float
    touchdown: float
    absorbed: float
    end: float
    before: float  # pelvis height when the crouch starts
    low: float
    lift_height: float  # pelvis height at take-off and touchdown
    bottom: float
    after: float  # pelvis height after the recovery
    speed_up: float

    @staticmethod
    def plan(start: float, before: float, low: float, lift_height: float, apex: float,
             bottom: float, after: float, crouch_time: float, recover_time: float) -> _Leap:
        speed_up = float(np.sqrt(2.0 * GRAVITY * apex))
        crouch_end = start + crouch_time * FPS
        takeoff = crouch_end + 2.0 * (lift_height - low) / speed_up * FPS
        touchdown = takeoff + 2.0 * speed_up / GRAVITY * FPS
        absorbed = touchdown + 2.0 * (lift_height - bottom) / speed_up * FPS
        return _Leap(start, crouch_end, takeoff, touchdown, absorbed,
                     absorbed + recover_time * FPS, before, low, lift_height, bottom, after, speed_up)

    def height(self, t: np.ndarray) -> np.ndarray:
        """Pelvis height at frames ``t`` (held outside the leap)."""
        y = np.where(t < self.start, self.before, self.after).astype(np.float64)
        phase = (t >= self.start) & (t < self.crouch_end)
        y[phase] = self.before + (self.low - self.before) * _ease(
            (t[phase] - self.start) / (self.crouch_end - self.start))
        phase = (t >= self.crouch_end) & (t < self.takeoff)
        tau = (t[phase] - self.crouch_end) / FPS
        push = (self.takeoff - self.crouch_end) / FPS
        y[phase] = self.low + 0.5 * self.speed_up / push * tau**2
        phase = (t >= self.takeoff) & (t < self.touchdown)
        tau = (t[phase] - self.takeoff) / FPS
        y[phase] = self.lift_height + self.speed_up * tau - 0.5 * GRAVITY * tau**2
        phase = (t >= self.touchdown) & (t < self.absorbed)
        tau = (t[phase] - self.touchdown) / FPS
        brake = (self.absorbed - self.touchdown) / FPS
        y[phase] = self.lift_height - self.speed_up * tau + 0.5 * self.speed_up / brake * tau**2
        phase = (t >= self.absorbed) & (t < self.end)
        y[phase] = self.bottom + (self.after - self.bottom) * _ease(
            (t[phase] - self.absorbed) / max(self.end - self.absorbed, 1e-9))
        return y


def _leap_chain(body: Body, count: int, start: float, stand: float, crouch: float, apex: float,
                absorb: float, crouch_time: float, rng: np.random.Generator) -> list[_Leap]:
    """``count`` leaps back to back: the landing crouch of one is the take-off crouch of the
    next, and only the last one recovers to standing."""
    toes_up = _TOE_HEIGHT + body.foot * np.sin(_FOOT_PITCH + _LIFT_PITCH)
    lift_height = toes_up + 0.975 * body.leg
    leaps, before = [], stand
    for k in range(count):
        last = k == count - 1
        height = apex * rng.uniform(0.85, 1.15)
        leap = _Leap.plan(start, before, stand - crouch, lift_height, height, stand - absorb,
                          stand if last else stand - absorb, crouch_time if k == 0 else 0.1,
                          0.45 if last else 0.0)
        leaps.append(leap)
        start, before = leap.end, leap.after
    return leaps


def _leap_heights(leaps: Sequence[_Leap], t: np.ndarray) -> np.ndarray:
    """Pelvis height through a chain of leaps."""
    y = leaps[0].height(t)
    for leap in leaps[1:]:
        later = t >= leap.start
        y[later] = leap.height(t[later])
    return y


def _leap_travel(leaps: Sequence[_Leap], distances: Sequence[float], t: np.ndarray) -> np.ndarray:
    """Forward pelvis travel through a chain of leaps: ahead of the feet at each take-off, behind
    them at each touchdown, never stopping between leaps (knots, then lightly smoothed)."""
    feet = np.concatenate([[0.0], np.cumsum(distances)])
    first, last = leaps[0], leaps[-1]
    knots = [(first.start, 0.0), (first.crouch_end, -0.1 * distances[0])]
    for k, leap in enumerate(leaps):
        ahead = 0.3 * distances[k]
        knots += [(leap.takeoff, feet[k] + ahead), (leap.touchdown, feet[k + 1] - ahead)]
    knots += [(last.absorbed, feet[-1] + 0.1 * distances[-1]), (last.end, feet[-1])]
    times, values = zip(*knots)
    return gaussian_smooth(np.interp(t, times, values), 1.5, truncate=3.0)


def _leap_foot(body: Body, leaps: Sequence[_Leap], t: np.ndarray, start: np.ndarray,
               heading: np.ndarray, distances: Sequence[float], yaw: float, tuck: float,
               ) -> tuple[np.ndarray, np.ndarray]:
    """Ankle targets and pitch of a foot that leaps: it rises on its toes in each push, flies
    with the pelvis (tucked up by ``tuck``), lands on its toes and rolls down flat, its toe fixed
    on the floor whenever it touches it."""
    ankles = np.repeat(start[None], len(t), axis=0)
    pitch = np.full(len(t), _FOOT_PITCH)
    yaw_t = np.full(len(t), yaw)
    flat = body.foot * _foot_direction(np.array(yaw), np.array(_FOOT_PITCH))
    high = body.foot * _foot_direction(np.array(yaw), np.array(_FOOT_PITCH + _LIFT_PITCH))
    planted = start.copy()
    for leap, distance in zip(leaps, distances):
        landing = planted + heading * distance
        toe_from, toe_to = planted + flat, landing + flat
        rise = leap.crouch_end + 0.3 * (leap.takeoff - leap.crouch_end)
        phase = (t >= rise) & (t < leap.takeoff)
        p = _FOOT_PITCH + _LIFT_PITCH * ((t[phase] - rise) / (leap.takeoff - rise)) ** 2
        ankles[phase] = toe_from - body.foot * _foot_direction(yaw_t[phase], p)
        pitch[phase] = p

        phase = (t >= leap.takeoff) & (t < leap.touchdown)
        u = (t[phase] - leap.takeoff) / (leap.touchdown - leap.takeoff)
        path = (toe_from - high) + ((toe_to - high) - (toe_from - high)) * u[:, None]
        lifted = leap.height(t[phase]) - leap.lift_height + tuck * np.sin(np.pi * u)
        ankles[phase] = path + _UP * lifted[:, None]
        pitch[phase] = _FOOT_PITCH + _LIFT_PITCH - 0.3 * np.sin(np.pi * u) ** 2

        flat_again = leap.touchdown + 0.5 * (leap.absorbed - leap.touchdown)
        phase = (t >= leap.touchdown) & (t < flat_again)
        p = _FOOT_PITCH + _LIFT_PITCH * (1.0 - _ease((t[phase] - leap.touchdown)
                                                     / (flat_again - leap.touchdown)))
        ankles[phase] = toe_to - body.foot * _foot_direction(yaw_t[phase], p)
        pitch[phase] = p
        ankles[t >= flat_again] = landing
        pitch[t >= flat_again] = _FOOT_PITCH
        planted = landing
    return ankles, pitch


def jump(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` two-footed jumps, ``in_place`` or ``forward`` (about 0.5–0.9 m each): crouch with
    the arms swung back, push off the toes swinging the arms up, fly, land on the toes, absorb."""
    forward = p["direction"] == "forward"
    distances = [rng.uniform(0.5, 0.9) * body.scale if forward else 0.0 for _ in range(p["count"])]
    apex = (rng.uniform(0.12, 0.2) if forward else rng.uniform(0.16, 0.3)) * body.scale
    leaps = _leap_chain(body, p["count"], 2.0, body.stand_height, rng.uniform(0.14, 0.22) * body.scale,
                        apex, rng.uniform(0.1, 0.16) * body.scale, 0.4, rng)
    frames = int(np.ceil(leaps[-1].end)) + 1
    t = np.arange(frames, dtype=np.float64)
    heading = _forward(state.yaw)
    program = _hold(body, state, frames)
    program.pelvis = (state.centre + heading * _leap_travel(leaps, distances, t)[:, None]
                      + _UP * _leap_heights(leaps, t)[:, None])
    for side in (LEFT, RIGHT):
        program.ankles[:, side], program.foot_pitch[:, side] = _leap_foot(
            body, leaps, t, state.ankles[side], heading, distances, float(state.foot_yaw[side]),
            tuck=0.35 * apex,
        )
    trunk_keys, arm_keys = [(0.0, 0.0)], [(0.0, 0.06)]
    lean = 0.1 + 0.3 * forward
    for leap in leaps:
        middle = 0.5 * (leap.takeoff + leap.touchdown)
        trunk_keys += [(leap.crouch_end, 0.45), (leap.takeoff, lean), (middle, 0.5 * lean),
                       (leap.absorbed, 0.35)]
        arm_keys += [(leap.crouch_end, -0.7), (middle, 1.9 * body.energy), (leap.absorbed, 0.4)]
    trunk_keys.append((leaps[-1].end, 0.0))
    arm_keys.append((leaps[-1].end, 0.06))
    trunk = gaussian_smooth(_keys(frames, trunk_keys), 1.5, truncate=3.0)
    program.trunk[:, 0] = trunk
    program.tilt[:, 0] += 0.6 * trunk
    program.neck[:, 0] -= 0.7 * trunk
    flex = gaussian_smooth(_keys(frames, arm_keys), 2.0, truncate=3.0)
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(body, side, flex, 0.2, 0.4)
    return program, replace(state, ankles=state.ankles + heading * sum(distances))


def hop(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` hops on the ``side`` leg, ``in_place`` or ``forward``: the other foot is lifted
    behind with the knee bent and the arms held out a little for balance, then put back down."""
    stance = SIDES.index(p["side"])
    free = 1 - stance
    forward = p["direction"] == "forward"
    heading, left = _forward(state.yaw), _leftward(state.yaw)
    lift_time = put_time = 0.5 * FPS
    distances = [rng.uniform(0.25, 0.4) * body.scale if forward else 0.0 for _ in range(p["count"])]
    stand = body.stand_height - 0.03 * body.scale
    leaps = _leap_chain(body, p["count"], lift_time, stand, 0.07 * body.scale,
                        rng.uniform(0.06, 0.1) * body.scale, 0.07 * body.scale, 0.2, rng)
    hopped = leaps[-1].end
    frames = int(np.ceil(hopped + put_time + 0.3 * FPS))
    t = np.arange(frames, dtype=np.float64)

    lifted = _keys(frames, [(0, 0.0), (lift_time, 1.0), (hopped, 1.0), (hopped + put_time, 0.0)])
    height = body.stand_height + (stand - body.stand_height) * lifted
    during = (t >= leaps[0].start) & (t < hopped)
    height[during] = _leap_heights(leaps, t[during])
    program = idle(body, state, frames, rng)
    shift = _SIGN[stance] * 0.06 * body.scale * left
    program.pelvis = (state.centre + heading * _leap_travel(leaps, distances, t)[:, None]
                      + lifted[:, None] * shift + _UP * height[:, None])
    program.ankles[:, stance], program.foot_pitch[:, stance] = _leap_foot(
        body, leaps, t, state.ankles[stance], heading, distances, float(state.foot_yaw[stance]), 0.0
    )
    end = replace(state, ankles=state.ankles + heading * sum(distances))

    hip = _SIGN[free] * body.lengths[_HIP[free]]
    tucked = program.pelvis + _to_world(state.yaw, np.array([hip, -0.6 * body.leg, -0.25 * body.leg]))
    floor = np.where(t[:, None] < 0.5 * (lift_time + hopped), state.ankles[free], end.ankles[free])
    program.ankles[:, free] = floor + (tucked - floor) * lifted[:, None]
    program.ankles[:, free, 1] += 0.05 * np.sin(np.pi * lifted)
    program.foot_pitch[:, free] += 0.5 * lifted
    program.tilt[:, 1] += _SIGN[stance] * 0.05 * lifted
    program.trunk[:, 0] += 0.08 * lifted
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + 0.3 * lifted, 0.12 + 0.45 * lifted, 0.3 + 0.5 * lifted
        )
    return program, end


# --------------------------------------------------------------------------- gestures


def _blend_arm(program: Program, side: int, wrist: np.ndarray, pole: np.ndarray,
               weight: np.ndarray) -> None:
    """Move one arm from its current curve toward (wrist, pole) curves by ``weight`` (T,)."""
    w = weight[:, None]
    program.wrists[:, side] += (wrist - program.wrists[:, side]) * w
    program.elbows[:, side] += (pole - program.elbows[:, side]) * w


def _arm_sides(side: str) -> tuple[int, ...]:
    return (LEFT, RIGHT) if side == "both" else (SIDES.index(side),)


def wave(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Raise the ``side`` hand(s) beside the head and wave ``count`` times (side to side)."""
    rate = rng.uniform(1.8, 2.5) * body.tempo
    up = rng.uniform(0.45, 0.6) * FPS
    waving = p["count"] / rate * FPS
    frames = int(np.ceil(2 * up + waving + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    t = np.arange(frames, dtype=np.float64)
    raised = _keys(frames, [(0, 0.0), (up, 1.0), (up + waving, 1.0), (2 * up + waving, 0.0)])
    sway = 0.1 * body.energy * body.arm / 0.53 * np.sin(
        2 * np.pi * p["count"] * np.clip((t - up) / waving, 0.0, 1.0)
    )
    for side in _arm_sides(p["side"]):
        s = _SIGN[side]
        hand = np.array([s * 0.24, 0.13, 0.12]) * body.arm / 0.53
        wrist = hand + np.stack([s * sway, -0.2 * np.abs(sway), np.zeros(frames)], axis=-1)
        _blend_arm(program, side, wrist, np.array([0.4 * s, -1.0, 0.0]), raised)
    if p["side"] != "both":
        program.neck[:, 1] += 0.12 * _SIGN[SIDES.index(p["side"])] * raised  # a glance at the hand
    return program, state


_RAISE = {"up": (2.95, 0.1), "forward": (1.57, 0.05), "sideways": (0.0, 1.57)}  # flex, abduction


def raise_arms(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Raise one or both arms ``up`` overhead, ``forward`` or ``sideways`` to shoulder height,
    hold, and lower them again."""
    rise = rng.uniform(0.6, 0.9) * FPS
    hold = rng.uniform(0.5, 1.2) * FPS
    frames = int(np.ceil(2 * rise + hold + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    raised = _keys(frames, [(0, 0.0), (rise, 1.0), (rise + hold, 1.0), (2 * rise + hold, 0.0)])
    flex, abduct = _RAISE[p["direction"]]
    if p["direction"] == "up" and rng.random() < 0.4:
        flex, abduct = 0.15, 2.9  # overhead by way of the sides
    for side in _arm_sides(p["side"]):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + (flex - 0.06) * raised, 0.12 + (abduct - 0.12) * raised,
            0.3 - 0.15 * raised,
        )
    program.trunk[:, 0] -= 0.04 * raised * (p["direction"] == "up")
    return program, state


def clap(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Bring the hands up in front of the chest and clap ``count`` times."""
    rate = rng.uniform(1.8, 2.6) * body.tempo
    up = rng.uniform(0.4, 0.55) * FPS
    clapping = p["count"] / rate * FPS
    frames = int(np.ceil(2 * up + clapping + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    t = np.arange(frames, dtype=np.float64)
    raised = _keys(frames, [(0, 0.0), (up, 1.0), (up + clapping, 1.0), (2 * up + clapping, 0.0)])
    apart, together = 0.34 * body.energy, 0.07
    phase = 2 * np.pi * p["count"] * np.clip((t - up) / clapping, 0.0, 1.0)
    gap = together + (apart - together) * (0.5 + 0.5 * np.cos(phase))
    reach = 0.62 * body.arm
    for side in (LEFT, RIGHT):
        s = _SIGN[side]
        inward = body.shoulder_half_width - 0.5 * gap  # hands meet on the midline
        ahead = np.sqrt(np.maximum(reach**2 - inward**2 - 0.2**2, 0.01))
        wrist = np.stack([-s * inward, np.full(frames, -0.2), ahead], axis=-1)
        _blend_arm(program, side, wrist, np.array([0.7 * s, -1.0, -0.2]), raised)
    return program, state


def punch(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Raise both fists to a guard and punch straight ahead ``count`` times with the ``side``
    arm, the chest turning into each punch."""
    hitter = SIDES.index(p["side"])
    guard_time = rng.uniform(0.4, 0.55) * FPS
    each = rng.uniform(0.42, 0.55) / body.tempo * FPS
    frames = int(np.ceil(2 * guard_time + p["count"] * each + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    t = np.arange(frames, dtype=np.float64)
    end = guard_time + p["count"] * each
    guard = _keys(frames, [(0, 0.0), (guard_time, 1.0), (end, 1.0), (end + guard_time, 0.0)])
    into = np.clip((t - guard_time) / each, 0.0, p["count"])
    cycle = into - np.floor(into)
    extended = np.where(into >= p["count"], 0.0,
                        np.where(cycle < 0.3, _ease(cycle / 0.3), 1.0 - _ease((cycle - 0.42) / 0.5)))
    scale = body.arm / 0.53
    for side in (LEFT, RIGHT):
        s = _SIGN[side]
        fist = np.array([-0.06 * s, 0.04, 0.2]) * scale
        target = np.repeat(fist[None], frames, axis=0)
        if side == hitter:
            strike = np.array([-0.16 * s, 0.0, 0.5]) * scale
            target = fist + (strike - fist) * extended[:, None]
        _blend_arm(program, side, target, np.array([0.35 * s, -1.0, -0.1]), guard)
    program.trunk[:, 2] -= 0.3 * _SIGN[hitter] * extended  # the punching shoulder comes forward
    program.trunk[:, 0] += 0.08 * guard
    program.neck[:, 1] += 0.2 * _SIGN[hitter] * extended  # the eyes stay on the target
    program.pelvis[:, 1] -= 0.03 * body.scale * guard
    return program, state


def kick(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Shift the weight onto the other foot and kick forward ``count`` times with the ``side``
    leg (knee up, snap the foot out ``low`` or ``high``, pull it back), then put the foot back."""
    kicker = SIDES.index(p["side"])
    heading = _forward(state.yaw)
    shift_time = rng.uniform(0.3, 0.4) * FPS
    chamber, snap, back = 0.25 * FPS, 0.17 * FPS, 0.25 * FPS
    each = chamber + snap + back
    down_time = 0.3 * FPS
    frames = int(np.ceil(2 * shift_time + p["count"] * each + down_time + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    high = p["height"] == "high"
    home = state.ankles[kicker]
    knee_up = home + heading * 0.2 * body.leg + _UP * 0.38 * body.leg
    reach = (0.9 if high else 0.85) * body.leg
    lift = (0.95 if high else 0.35) * body.leg
    out = home + heading * reach + _UP * lift
    keys_ankle = [(0, home), (shift_time, home)]
    keys_pitch = [(0, _FOOT_PITCH), (shift_time, _FOOT_PITCH)]
    keys_lean = [(0, 0.0), (shift_time, 0.0)]
    now = shift_time
    for _ in range(p["count"]):
        keys_ankle += [(now + chamber, knee_up), (now + chamber + snap, out), (now + each, knee_up)]
        keys_pitch += [(now + chamber, 0.9), (now + chamber + snap, -0.3 if high else 0.3), (now + each, 0.9)]
        keys_lean += [(now + chamber, -0.05), (now + chamber + snap, -0.25 if high else -0.1),
                      (now + each, -0.05)]
        now += each
    keys_ankle.append((now + down_time, home))
    keys_pitch.append((now + down_time, _FOOT_PITCH))
    keys_lean.append((now + down_time, 0.0))
    program.ankles[:, kicker] = _keys(frames, keys_ankle)
    program.foot_pitch[:, kicker] = _keys(frames, keys_pitch)
    weight = _keys(frames, [(0, 0.0), (shift_time, 1.0), (now + down_time, 1.0),
                            (now + down_time + shift_time, 0.0)])
    toward = -_SIGN[kicker] * (0.5 * body.step_width + 0.01) * _leftward(state.yaw)
    program.pelvis += weight[:, None] * toward
    program.pelvis[:, 1] -= 0.03 * body.scale * weight
    lean = _keys(frames, keys_lean)
    program.trunk[:, 0] += lean
    program.tilt[:, 0] += 0.6 * lean
    program.tilt[:, 1] -= _SIGN[kicker] * 0.05 * weight
    program.neck[:, 0] -= lean
    for side in (LEFT, RIGHT):
        forward_arm = 0.5 if side != kicker else -0.2
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + forward_arm * weight, 0.12 + 0.5 * weight, 0.3 + 0.6 * weight
        )
    return program, state


def squat(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` squats, ``shallow`` or ``deep``: hips back and down, heels flat, trunk leaning
    forward and arms reaching forward for balance."""
    depth = (0.22 if p["depth"] == "shallow" else 0.36) * body.leg / 0.826 * rng.uniform(0.92, 1.08)
    down, hold = rng.uniform(0.65, 0.9) * FPS, rng.uniform(0.15, 0.35) * FPS
    each = 2 * down + hold
    frames = int(np.ceil(p["count"] * each + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    keys = [(0.0, 0.0)]
    for k in range(p["count"]):
        keys += [(k * each + down, 1.0), (k * each + down + hold, 1.0), ((k + 1) * each, 0.0)]
    bend = _keys(frames, keys)
    program.pelvis[:, 1] -= depth * bend
    program.pelvis -= (0.55 * depth * bend)[:, None] * _forward(state.yaw)
    program.tilt[:, 0] += 1.1 * depth * bend
    program.trunk[:, 0] += 0.9 * depth * bend
    program.neck[:, 0] -= 1.2 * depth * bend
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + 1.4 * bend * depth / 0.36, 0.12, 0.3 - 0.1 * bend
        )
    return program, state


def bow(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Bend forward at the hips and waist, ``slight`` (about 25°) or ``deep`` (about 50°), pause,
    and come back up; the arms stay along the body."""
    angle = np.radians(25.0 if p["depth"] == "slight" else 50.0) * rng.uniform(0.9, 1.1)
    down, hold = rng.uniform(0.7, 0.9) * FPS, rng.uniform(0.4, 0.8) * FPS
    frames = int(np.ceil(2 * down + hold + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    bend = _keys(frames, [(0, 0.0), (down, 1.0), (down + hold, 1.0), (2 * down + hold, 0.0)])
    program.tilt[:, 0] += 0.45 * angle * bend
    program.trunk[:, 0] += 0.55 * angle * bend
    program.neck[:, 0] += 0.2 * bend
    program.pelvis -= (0.12 * angle * body.scale * bend)[:, None] * _forward(state.yaw)
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + 0.6 * angle * bend, 0.12 - 0.06 * bend, 0.3
        )
    return program, state


def _seat_transition(body: Body, state: State, duration: float, standing_up: bool) -> Program:
    """Move between standing and the seat in ``duration`` frames: the trunk leans forward to keep
    the weight over the feet while the hips travel back and down (or up and forward)."""
    frames = int(np.ceil(duration + 0.3 * FPS))
    standing = _hold(body, replace(state, seated=False), frames)
    seated = _hold(body, replace(state, seated=True), frames)
    if standing_up:
        back = _keys(frames, [(0.25 * duration, 1.0), (0.8 * duration, 0.0)])
        down = _keys(frames, [(0.2 * duration, 1.0), (duration, 0.0)])
        lean = _keys(frames, [(0, 0.0), (0.35 * duration, 1.0), (duration, 0.0)])
    else:
        back = _keys(frames, [(0.05 * duration, 0.0), (0.75 * duration, 1.0)])
        down = _keys(frames, [(0.15 * duration, 0.0), (duration, 1.0)])
        lean = _keys(frames, [(0, 0.0), (0.55 * duration, 1.0), (duration, 0.0)])
    progress = 0.5 * (back + down)  # 0 standing, 1 seated
    program = standing
    for name in ("tilt", "trunk", "wrists", "elbows"):
        a, b = getattr(standing, name), getattr(seated, name)
        setattr(program, name, a + (b - a) * progress.reshape((-1,) + (1,) * (a.ndim - 1)))
    program.pelvis = standing.pelvis + (seated.pelvis - standing.pelvis) * back[:, None]
    program.pelvis[:, 1] = standing.pelvis[:, 1] + (seated.pelvis[:, 1] - standing.pelvis[:, 1]) * down
    program.trunk[:, 0] += 0.55 * lean
    program.tilt[:, 0] += 0.25 * lean
    program.neck[:, 0] -= 0.5 * lean
    return program


def sit_down(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Sit down on an implied seat behind the feet: lean forward, hips back and down."""
    duration = (2.2 if p["speed"] == "slow" else 1.6) * rng.uniform(0.9, 1.1) * FPS
    return _seat_transition(body, state, duration, standing_up=False), replace(state, seated=True)


def stand_up(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Stand up from the seat: lean forward over the feet, push up, straighten."""
    duration = (2.2 if p["speed"] == "slow" else 1.6) * rng.uniform(0.9, 1.1) * FPS
    return _seat_transition(body, state, duration, standing_up=True), replace(state, seated=False)


# --------------------------------------------------------------------------- families


@dataclass(frozen=True)
class Family:
    """An action family: its generator, how its parameters are drawn, and the posture it needs
    and leaves (actions only chain where the posture matches)."""

    generate: Callable[[Body, State, dict, np.random.Generator], tuple[Program, State]]
    sample: Callable[[np.random.Generator], dict]
    seated_before: bool = False
    seated_after: bool = False


def _pick(rng: np.random.Generator, options: Sequence, weights: Sequence[float] | None = None):
    """One option, as a plain Python value (JSON-friendly)."""
    index = int(rng.choice(len(options), p=None if weights is None else np.asarray(weights) / sum(weights)))
    return options[index]


def _count(rng: np.random.Generator, low: int, high: int) -> int:
    return int(rng.integers(low, high + 1))


ACTIONS: dict[str, Family] = {
    "walk": Family(walk, lambda r: {"steps": _count(r, 3, 10),
                                    "speed": _pick(r, ("slow", "normal", "fast"))}),
    "walk_backwards": Family(walk_backwards, lambda r: {"steps": _count(r, 3, 7),
                                                        "speed": _pick(r, ("slow", "normal"))}),
    "walk_circle": Family(walk_circle, lambda r: {
        "direction": _pick(r, ("clockwise", "counterclockwise")),
        "radius": round(float(r.uniform(0.6, 0.95)), 2)}),
    "jog": Family(jog, lambda r: {"steps": _count(r, 6, 13), "speed": _pick(r, ("slow", "normal"))}),
    "run": Family(run, lambda r: {"steps": _count(r, 6, 15), "speed": _pick(r, ("normal", "fast"))}),
    "sidestep": Family(sidestep, lambda r: {"side": _pick(r, SIDES), "count": _count(r, 2, 4)}),
    "turn": Family(turn, lambda r: {"side": _pick(r, SIDES), "angle": _pick(r, (45, 90, 180), (1, 3, 2))}),
    "jump": Family(jump, lambda r: {"direction": _pick(r, ("in_place", "forward")),
                                    "count": _count(r, 1, 3)}),
    "hop": Family(hop, lambda r: {"side": _pick(r, SIDES), "count": _count(r, 2, 5),
                                  "direction": _pick(r, ("in_place", "forward"))}),
    "wave": Family(wave, lambda r: {"side": _pick(r, ("left", "right", "both"), (2, 2, 1)),
                                    "count": _count(r, 2, 5)}),
    "raise_arms": Family(raise_arms, lambda r: {"side": _pick(r, ("left", "right", "both")),
                                                "direction": _pick(r, ("up", "forward", "sideways"))}),
    "clap": Family(clap, lambda r: {"count": _count(r, 2, 7)}),
    "punch": Family(punch, lambda r: {"side": _pick(r, SIDES), "count": _count(r, 1, 4)}),
    "kick": Family(kick, lambda r: {"side": _pick(r, SIDES), "height": _pick(r, ("low", "high")),
                                    "count": _count(r, 1, 2)}),
    "squat": Family(squat, lambda r: {"count": _count(r, 1, 3), "depth": _pick(r, ("shallow", "deep"))}),
    "bow": Family(bow, lambda r: {"depth": _pick(r, ("slight", "deep"))}),
    "sit_down": Family(sit_down, lambda r: {"speed": _pick(r, ("slow", "normal"))}, seated_after=True),
    "stand_up": Family(stand_up, lambda r: {"speed": _pick(r, ("slow", "normal"))},
                       seated_before=True),
}


# --------------------------------------------------------------------------- whole clips


@dataclass(frozen=True)
class Composition:
    """A clip before rendering: its program, the body it is made on and each action's frame
    range ``[start, end)``."""

    program: Program
    body: Body
    segments: tuple[tuple[int, int], ...]


def compose(actions: Sequence[tuple[str, dict]], rng: np.random.Generator,
            min_frames: int = 40) -> Composition:
    """Chain actions on a random body, with short idles around and sometimes between them, and
    cross-fade the posture at every boundary; each action starts where the previous one ended
    (same feet, heading and posture). Cheap: nothing is rendered yet."""
    body = sample_body(rng)
    state = initial_state(body, rng, seated=ACTIONS[actions[0][0]].seated_before)
    programs = [idle(body, state, int(rng.integers(4, 14)), rng)]
    segments = []
    frame = len(programs[0])
    for i, (name, params) in enumerate(actions):
        program, state = ACTIONS[name].generate(body, state, params, rng)
        segments.append((frame, frame + len(program)))
        programs.append(program)
        frame += len(program)
        if i < len(actions) - 1 and rng.random() < 0.4:
            programs.append(idle(body, state, int(rng.integers(3, 9)), rng))
            frame += len(programs[-1])
    programs.append(idle(body, state, max(int(rng.integers(4, 14)), min_frames - frame), rng))
    boundaries = np.cumsum([len(p) for p in programs])[:-1]
    program = blend_boundaries(Program.concat(programs), boundaries)
    return Composition(program, body, tuple(segments))
