"""A motion as a :class:`Program` of per-frame curves, and its rendering to joint positions:
forward kinematics of the trunk, two-bone IK of the limbs, the pelvis lowered wherever a leg
would not reach; holds and idles between actions; the calibrated high-frequency texture."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from m2d2m.motion.representation.skeleton import T2M
from pipelines.synthetic.body import (
    ANKLE,
    COLLAR,
    COLLAR_REST,
    ELBOW,
    FOOT_PITCH,
    FPS,
    HIP,
    KNEE,
    LEFT,
    NECK_REST,
    REACH,
    RIGHT,
    SHOULDER,
    SIGN,
    SPINE,
    TOE,
    WRIST,
    Body,
    State,
    rest_arms,
    seated_pelvis,
)
from pipelines.synthetic.maths import (
    UP,
    ease,
    foot_direction,
    forward_direction,
    leftward,
    rotation,
    smooth_cover,
    two_bone,
)


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
        return Program(**{f.name: np.concatenate([getattr(p, f.name) for p in programs]) for f in fields(Program)})


# Channels that are cross-faded between actions; the rest are continuous by construction.
_BLENDED = ("tilt", "trunk", "neck", "wrists", "elbows")


def blend_boundaries(program: Program, boundaries: Sequence[int], frames: int = 8) -> Program:
    """Fade out any jump of the posture channels at each boundary over ``frames`` (0.4 s):
    the new action starts from the previous pose and converges to its own curve."""
    program = replace(program, **{name: getattr(program, name).copy() for name in _BLENDED})
    weights = 1.0 - ease((np.arange(frames) + 1.0) / (frames + 1.0))
    for b in boundaries:
        if not 0 < b < len(program):
            continue
        span = min(frames, len(program) - b)
        for name in _BLENDED:
            x = getattr(program, name)
            jump = x[b - 1] - x[b]
            x[b : b + span] += jump[None] * weights[:span].reshape((-1,) + (1,) * jump.ndim)
    return program


def hold_pose(body: Body, state: State, frames: int) -> Program:
    """Still standing (or seated) pose, the base every other program edits."""
    wrists, elbows = rest_arms(body)
    if state.seated:
        pelvis = seated_pelvis(body, state)
        tilt, trunk = (-0.12, 0.0), (0.22, 0.0, 0.0)
        for side in (LEFT, RIGHT):
            wrists[side] = np.array([-0.02 * SIGN[side], -0.62, 0.55]) * body.arm
            elbows[side] = np.array([0.5 * SIGN[side], 0.0, -1.0])
    else:
        pelvis = state.centre + UP * body.stand_height
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
        foot_pitch=constant((FOOT_PITCH, FOOT_PITCH)),
    )


def idle(body: Body, state: State, frames: int, rng: np.random.Generator) -> Program:
    """Standing or sitting still, with a slow weight shift and breathing so nothing is frozen."""
    program = hold_pose(body, state, frames)
    t = np.arange(frames) / FPS
    phase = rng.uniform(0, 2 * np.pi, size=3)
    shift = 0.008 * np.sin(2 * np.pi * t / 3.1 + phase[0])
    if not state.seated:
        program.pelvis += shift[:, None] * leftward(state.yaw)[None]
        program.tilt[:, 1] -= 1.5 * shift
    program.trunk[:, 0] += 0.015 * np.sin(2 * np.pi * t / 3.7 + phase[1])
    program.neck[:, 1] += 0.06 * np.sin(2 * np.pi * t / 4.3 + phase[2])
    return program


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
        return replace(
            program,
            **{
                name: curve + level * band_noise(frames, curve.shape[1:], rng, self.low_hz)
                for name, (curve, level) in changes.items()
            },
        )


def band_noise(
    frames: int, shape: tuple[int, ...], rng: np.random.Generator, low_hz: float, fps: float = FPS
) -> np.ndarray:
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


def _fit_pelvis_height(pelvis: np.ndarray, r0: np.ndarray, ankles: np.ndarray, body: Body) -> np.ndarray:
    """Lower the wished pelvis height, smoothly, wherever a leg could not reach its ankle target;
    elsewhere the wished curve (a jump's parabola, say) is kept as it is."""
    reach = REACH * body.leg
    highest = np.full(len(pelvis), np.inf)
    for side in (LEFT, RIGHT):
        hip = pelvis + r0 @ body.offsets[HIP[side]]
        horizontal = (hip[:, 0] - ankles[:, side, 0]) ** 2 + (hip[:, 2] - ankles[:, side, 2]) ** 2
        vertical = np.sqrt(np.maximum(reach**2 - horizontal, 0.0))
        highest = np.minimum(highest, ankles[:, side, 1] + vertical - (hip[:, 1] - pelvis[:, 1]))
    fitted = pelvis.copy()
    fitted[:, 1] -= smooth_cover(np.maximum(pelvis[:, 1] - highest, 0.0), 3)
    return fitted


def program_joints(program: Program, body: Body) -> np.ndarray:
    """Joint positions (T, 22, 3) of a program: FK for the pelvis, spine, neck and collars, two-bone
    IK for the arms (wrist targets in the chest frame) and the legs (world ankle targets)."""
    frames = len(program)
    offsets = body.offsets
    joints = np.empty((frames, T2M.num_joints, 3))
    r0 = rotation(np.stack([program.yaw, program.tilt[:, 0], -program.tilt[:, 1]], axis=-1))
    joints[:, 0] = _fit_pelvis_height(program.pelvis, r0, program.ankles, body)
    for joint in (1, 2, 3):
        joints[:, joint] = joints[:, 0] + r0 @ offsets[joint]

    trunk = program.trunk
    rot = r0
    for joint, share in SPINE:
        rot = rot @ rotation(share * np.stack([trunk[:, 2], trunk[:, 0], -trunk[:, 1]], axis=-1))
        child = {3: 6, 6: 9, 9: 12}[joint]
        joints[:, child] = joints[:, joint] + rot @ offsets[child]
    chest = rot
    neck = chest @ rotation(np.stack([program.neck[:, 1], NECK_REST + program.neck[:, 0], np.zeros(frames)], axis=-1))
    joints[:, 15] = joints[:, 12] + neck @ offsets[15]

    for side in (LEFT, RIGHT):
        collar, shoulder, elbow, wrist = COLLAR[side], SHOULDER[side], ELBOW[side], WRIST[side]
        joints[:, collar] = joints[:, 9] + chest @ offsets[collar]
        collar_rot = chest @ rotation(np.array([0.0, 0.0, SIGN[side] * COLLAR_REST]))
        joints[:, shoulder] = joints[:, collar] + collar_rot @ offsets[shoulder]
        target = joints[:, shoulder] + np.einsum("tij,tj->ti", chest, program.wrists[:, side])
        pole = np.einsum("tij,tj->ti", chest, program.elbows[:, side])
        joints[:, elbow], joints[:, wrist] = two_bone(joints[:, shoulder], target, pole, body.upper_arm, body.forearm)

        hip, knee, ankle, toe = HIP[side], KNEE[side], ANKLE[side], TOE[side]
        knee_pole = forward_direction(0.5 * (program.foot_yaw[:, side] + program.yaw)) + 0.6 * UP
        joints[:, knee], joints[:, ankle] = two_bone(
            joints[:, hip], program.ankles[:, side], knee_pole, body.thigh, body.shin
        )
        joints[:, toe] = joints[:, ankle] + body.foot * foot_direction(
            program.foot_yaw[:, side], program.foot_pitch[:, side]
        )
    return joints
