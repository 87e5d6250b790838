"""Token samplers of M2D2M: single actions, Two-Phase Sampling (M2D2M (Chi et al., 2024),
Algorithm 1), the paper's multi-motion baselines on the same model, and editing by fixed tokens.

The loop (:meth:`TokenSampler.sample`) is Algorithm 1's, written the way diffusers writes one: the
model's prediction, then the schedule's step. At every jump from t to s the denoiser gives
p_θ(z̃_0 | z_t, y) (classifier-free guidance s, eq. 9; VQ-Diffusion's truncation r) and
:meth:`TransitionSchedule.step` draws z_s from the posterior it implies (eq. 4). What differs
between the methods is only how a request's actions are laid out as *rows* of a batch, which one
object holds (:class:`RowLayout`):

- ``tps``: for t = T … T_s+1 one row per request, its actions concatenated and its conditions
  concatenated (joint phase); for t = T_s … 1 one row per action (independent phase).
- ``independent``: one row per action for all t (the paper's T2M-GPT baseline: tokens sampled
  alone, concatenated before decoding). It is ``tps`` with T_s = T.
- ``handshake``: one row per action, each action after the first extended by H tokens that it shares
  with the end of the previous one; at every step the overlapping x0 probabilities are blended
  with a linear ramp and the drawn tokens copied, so neighbours share one transition (DoubleTake's
  first take, priorMDM/priorMDM ``sample/double_take.py``, in token space).
- ``slerp``: one row per action, every action after the first shortened by the transition window;
  the motion-level gap filling is :func:`m2d2m.motion.transforms.joining.bridge` (TEACH's SLERP baseline).

The sampler's state is every request's token *stream* (its actions in order; under handshake each
later action preceded by its copy of the shared tokens), one after another; the rows of either
phase hold the streams in order, each token once. Randomness is per request: each request has its
own generator and draws, at every step, one uniform per token of its stream, whatever the rows
look like. Hence a request's result does not depend on what else is in the batch, and ``tps``
with T_s = T reproduces ``independent`` draw for draw.

Rows of very different lengths are not padded to the longest: the denoiser runs once per group of
rows of similar length (:func:`length_groups`), which on test sets of 10- to 50-token actions halves
the work of a step. Padded positions never reach the posterior. What does not change from step to
step is computed once per phase: the text's features and every block's cross-attention keys and
values (:class:`m2d2m.networks.m2d2m_denoiser.Condition`), for the conditional and the null rows
of classifier-free guidance together, and where the real positions are, as index tensors built
from the lengths the host knows. A step only gathers and scatters through them, so on a GPU it
never waits for the device (``tests/test_host_syncs.py``). With the ``compile`` option the
denoiser's passes run compiled at bucketed shapes (:mod:`m2d2m.compiling`).

Fewer steps than the schedule's T (``steps``) jump from t to s < t with the exact posterior
q(z_s | z_t, z0) (:meth:`TransitionSchedule.posterior_probs`; VQ-Diffusion's fast sampling
approximates that jump by a one-step posterior at s), on a grid that keeps T_s one of its points
(:func:`timesteps`); at ``steps`` = T it is the full sampler draw for draw.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import accumulate

import torch
import torch.nn.functional as F
from torch import Tensor

from m2d2m.compiling import Compiled, bucket, compiles, pad_to_bucket
from m2d2m.generators.m2d2m.options import M2D2MOptions
from m2d2m.generators.token_model import FREE
from m2d2m.networks.m2d2m_denoiser import Condition, MotionDenoiser, action_offsets, guided_logits
from m2d2m.processes.discrete_diffusion import TransitionSchedule
from m2d2m.text import TextEncoder, encode_actions


@dataclass
class TokenRequest:
    """One sequence to generate: its actions in order, each action's length in tokens, a seed.

    ``given`` (optional, Σ lengths long): tokens to keep (in-betweening, prefix or suffix
    completion), :data:`FREE` where the sampler decides. ``actions[i]`` is one action's condition:
    its sentence, or several sentences whose token features are concatenated.
    """

    actions: list[list[str]]
    lengths: list[int]
    seed: int = 0
    given: Tensor | None = None

    def __post_init__(self) -> None:
        if not self.actions or len(self.actions) != len(self.lengths):
            raise ValueError("a request needs one length per action and at least one action")
        if any(not sentences for sentences in self.actions):
            raise ValueError("every action needs at least one sentence")
        if min(self.lengths) < 1:
            raise ValueError(f"every action needs at least one token, got lengths {self.lengths}")
        if self.given is not None and tuple(self.given.shape) != (sum(self.lengths),):
            raise ValueError(f"given must hold {sum(self.lengths)} tokens, got shape {tuple(self.given.shape)}")


def switch_step(ts: int | None, steps: int) -> int:
    """T_s, defaulting to the paper's 90 of 100 steps scaled to the schedule's T."""
    return round(0.9 * steps) if ts is None else ts


def timesteps(total: int, taken: int | None, switch: int) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """The reverse jumps (t, s) of the joint phase (t > ``switch``) and of the independent phase, for
    ``taken`` of the schedule's ``total`` steps (None: all of them, every jump one step).

    The phases share the steps in proportion to their spans (at least one each when its span is not
    empty) and each is cut into jumps as even as whole steps allow, so T_s stays a point of the grid:
    T_s scales with the number of steps."""
    taken = total if taken is None else taken
    if not 0 <= switch <= total or not 1 <= taken <= total:
        raise ValueError(f"need 0 <= T_s <= T and 1 <= steps <= T = {total}, got T_s = {switch}, steps = {taken}")
    joint_span, independent_span = total - switch, switch
    joint = min(joint_span, max(1, round(taken * joint_span / total))) if joint_span else 0
    independent = min(independent_span, max(1, taken - joint)) if independent_span else 0
    return _jumps(total, switch, joint), _jumps(switch, 0, independent)


def _jumps(start: int, stop: int, count: int) -> list[tuple[int, int]]:
    """``count`` jumps from ``start`` down to ``stop``, their lengths as even as whole steps allow."""
    if count == 0:
        return []
    points = [start - round(i * (start - stop) / count) for i in range(count + 1)]
    return list(zip(points[:-1], points[1:]))


def truncate(probs: Tensor, rate: float) -> Tensor:
    """VQ-Diffusion's truncation: keep the most probable codes until ``rate`` of the mass is covered
    (the top code always stays), zero the rest and renormalise over the last dimension."""
    if rate >= 1.0:
        return probs
    ordered, order = probs.sort(dim=-1, descending=True)
    keep_sorted = (ordered.cumsum(dim=-1) - ordered) < rate
    keep = torch.zeros_like(keep_sorted).scatter(-1, order, keep_sorted)
    kept = probs * keep
    return kept / kept.sum(dim=-1, keepdim=True)


def length_groups(lengths: list[int], spread: float = 0.75) -> list[list[int]]:
    """Row indices grouped for one forward pass each, longest rows first.

    Every row of a group is at least ``spread`` times as long as the group's longest, so padding
    stays under a quarter of a group's tokens (less attention, which grows with the square), while
    the number of passes grows only with the logarithm of the longest-to-shortest ratio.
    """
    order = sorted(range(len(lengths)), key=lambda i: -lengths[i])
    groups: list[list[int]] = []
    for i in order:
        if groups and lengths[i] >= spread * lengths[groups[-1][0]]:
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups


class TokenSampler:
    """Reverse diffusion over motion tokens for a denoiser, its text encoder and its schedule.

    Works on the device the denoiser is on; the schedule is moved there. An η in the options
    builds the dynamic schedule's matrices for that η once (a few hundred milliseconds at K = 512, T = 100).
    With the ``compile`` option the denoiser runs through ``torch.compile`` at bucketed shapes
    (:mod:`m2d2m.compiling`), compiled once per shape for the sampler's life.
    """

    def __init__(
        self,
        denoiser: MotionDenoiser,
        text_encoder: TextEncoder,
        schedule: TransitionSchedule,
        reuse_condition: bool = True,
    ) -> None:
        self.denoiser = denoiser
        self.text_encoder = text_encoder
        self.schedule = schedule
        self.reuse_condition = reuse_condition  # False recomputes the text's keys and values every step
        self._at_eta: dict[float, TransitionSchedule] = {}
        self._compiled: Compiled[Tensor] | None = None

    @property
    def device(self) -> torch.device:
        return next(self.denoiser.parameters()).device

    @torch.no_grad()
    def sample(
        self,
        requests: list[TokenRequest],
        options: M2D2MOptions = M2D2MOptions(),
        progress: Callable[[int], None] | None = None,
    ) -> list[list[Tensor]]:
        """Tokens for each request, one (length,) long tensor per action (the *generated* tokens:
        under ``slerp`` later actions are ``slerp`` tokens shorter; under ``handshake`` the
        shared tokens belong to the earlier action). ``progress(s)`` is called after each jump
        with the step s it reached (T − s of T done)."""
        options.check(self.schedule.steps)
        schedule = self._schedule(options.eta)
        if not requests:
            return []
        if options.method == "handshake" and min(n for r in requests for n in r.lengths) < options.handshake:
            raise ValueError(f"handshake sampling needs every action to be at least {options.handshake} tokens long")
        if options.method == "slerp":
            requests = [_shortened(request, options.slerp) for request in requests]
        was_training = self.denoiser.training
        self.denoiser.eval()
        self.text_encoder.eval()
        try:
            return self._reverse(requests, options, schedule, progress)
        finally:
            self.denoiser.train(was_training)
            self.text_encoder.train(was_training)

    def _reverse(
        self,
        requests: list[TokenRequest],
        options: M2D2MOptions,
        schedule: TransitionSchedule,
        progress: Callable[[int], None] | None,
    ) -> list[list[Tensor]]:
        """Algorithm 1 on a batch of requests; the numbers are its lines."""
        layout = RowLayout.of(requests, options, schedule.steps, self.device)
        generators = [torch.Generator(device=self.device).manual_seed(int(r.seed)) for r in requests]
        z = layout.settle(layout.prior(schedule, generators))  # 1: z_T ~ p(z_T), kept tokens in place
        for phase in layout.phases:  # 3: the joint rows, then 6–7: one row per action
            model = self._model(phase, options)  # 2: y, the rows' text, encoded once per phase
            for t, s in phase.jumps:
                x0 = layout.blend(model(z, t))  # p_θ(z̃_0 | z_t, y), guided (eq. 9)
                z = layout.settle(schedule.step(z, x0, t, s, layout.uniforms(generators)))  # 4, 8
                if progress is not None:
                    progress(s)
        return layout.split(z)  # 11: each action's z_0

    def _schedule(self, eta: float | None) -> TransitionSchedule:
        """The schedule at ``eta`` on the model's device, built once per η (with the jumps it has
        taken cached in it); a ``uniform`` schedule has no η to change."""
        schedule = self.schedule
        if eta is not None and schedule.config.kind == "dynamic" and float(eta) != schedule.config.eta:
            if float(eta) not in self._at_eta:
                self._at_eta[float(eta)] = schedule.with_eta(eta)
            schedule = self._at_eta[float(eta)]
        return schedule.to(self.device) if schedule.device != self.device else schedule

    def _model(self, phase: Phase, options: M2D2MOptions) -> PhaseModel:
        """The denoiser over ``phase``'s rows."""
        denoise, compiled = self._forward(options)
        return PhaseModel(self.denoiser, self.text_encoder, phase, options, denoise, compiled, self.reuse_condition)

    def _forward(self, options: M2D2MOptions) -> tuple[Callable[..., Tensor], bool]:
        """The denoiser's forward pass the options ask for, and whether it is compiled (then the
        passes are padded to buckets)."""
        if not compiles(options.compile, self.device):
            return self.denoiser.denoise, False
        if self._compiled is None or self._compiled.function.__self__ is not self.denoiser:
            self._compiled = Compiled(self.denoiser.denoise, "the denoiser", cuda=self.device.type == "cuda")
        return self._compiled, self._compiled.compiled


class PhaseModel:
    """``model(z_t, t)`` of the loop for one phase: p_θ(z̃_0 | z_t, y) (N, K) in float64 for every
    token of the streams, guided (eq. 9) and truncated.

    Each step runs one forward pass per length group of the phase's rows, the conditional and the
    null rows of guidance together. What stays the same over the phase's steps is prepared here
    once: the rows' text, and each pass's rows, validity mask, action offsets and text condition."""

    def __init__(
        self,
        denoiser: MotionDenoiser,
        text_encoder: TextEncoder,
        phase: Phase,
        options: M2D2MOptions,
        denoise: Callable[..., Tensor],
        compiled: bool,
        reuse_condition: bool,
    ) -> None:
        self.denoiser, self.phase, self.options, self.denoise = denoiser, phase, options, denoise
        self.text, self.text_mask = self._text(text_encoder, compiled)
        self.groups = self._groups(compiled, reuse_condition)

    def __call__(self, z: Tensor, t: int) -> Tensor:
        phase = self.phase
        batch = phase.batch(z, fill=self.denoiser.mask_id)
        codes = self.denoiser.config.codebook_size
        x0 = torch.zeros(len(phase.rows), phase.width, codes, dtype=torch.float64, device=z.device)
        for group in self.groups:
            x0[group.real, : group.width] = self._x0(batch, group, t)
        return phase.tokens(x0)

    def _text(self, text_encoder: TextEncoder, compiled: bool) -> tuple[Tensor, Tensor]:
        """The rows' text features and mask; a row whose sentences are all empty asks for no text
        and gets the null condition of classifier-free guidance. Compiled, the text is padded to a
        bucket of tokens (masked keys: nothing changes at the real ones)."""
        rows = self.phase.rows
        text, text_mask = encode_actions(text_encoder, [row.condition for row in rows])
        unconditional = [not any(s.strip() for s in row.condition) for row in rows]
        if any(unconditional):
            nulled = torch.tensor(unconditional).to(text.device, non_blocking=True)
            text, text_mask = self.denoiser.nullify(text, text_mask, nulled)
        if compiled:
            text, text_mask = pad_to_bucket(text, 1), pad_to_bucket(text_mask, 1)
        return text, text_mask

    def _condition(self, text: Tensor, text_mask: Tensor) -> Condition:
        """The denoiser's condition of the rows, followed, when guided, by as many null rows."""
        if self.options.guidance == 0.0:
            return self.denoiser.condition(text, text_mask)
        every = torch.ones(text.shape[0], dtype=torch.bool, device=text.device)
        null_text, null_mask = self.denoiser.nullify(text, text_mask, every)
        return self.denoiser.condition(torch.cat([text, null_text]), torch.cat([text_mask, null_mask]))

    def _groups(self, compiled: bool, reuse_condition: bool) -> list[_Group]:
        """The forward passes of a step, one per length group of the phase, with what they keep
        over the phase; compiled, each is padded to a bucket of rows and of tokens."""
        phase, options = self.phase, self.options
        condition = self._condition(self.text, self.text_mask) if reuse_condition else None
        passes = _passes(options)
        groups = []
        for members in phase.groups:
            width = phase.rows[members[0]].length
            size, padded = (bucket(len(members)), bucket(width, smallest=8)) if compiled else (len(members), width)
            index = torch.tensor(members + members[:1] * (size - len(members))).to(
                phase.cells.device, non_blocking=True
            )
            groups.append(
                _Group(
                    index,
                    len(members),
                    width,
                    padded,
                    F.pad(phase.valid[index, :width], (0, padded - width)).repeat(passes, 1),
                    F.pad(phase.offsets[index, :width], (0, 0, 0, padded - width)).repeat(passes, 1, 1),
                    None if condition is None else condition.rows(_guided_rows(index, len(phase.rows), options)),
                )
            )
        return groups

    def _x0(self, batch: Tensor, group: _Group, t: int) -> Tensor:
        """Guided, truncated p(z0 | z_t) (rows, width, K) in float64 of a group's real rows: one
        forward pass of the conditional and null rows together (``group.condition`` holds both
        when guided)."""
        options = self.options
        tokens = batch[group.index, : group.width]
        if group.padded > group.width:
            tokens = F.pad(tokens, (0, group.padded - group.width), value=self.denoiser.mask_id)
        condition = group.condition
        if condition is None:
            condition = self._condition(self.text[group.index], self.text_mask[group.index])
        steps = torch.full((1,), t, dtype=torch.long, device=batch.device)  # one t for every row: embedded once
        logits = self.denoise(tokens.repeat(_passes(options), 1), group.valid, steps, condition, group.offsets)
        cond = logits[: group.rows, : group.width]
        if _passes(options) == 2:  # the null rows follow the group's (padded) rows
            start = group.index.shape[0]
            logits = guided_logits(cond, logits[start : start + group.rows, : group.width], options.guidance)
        else:
            logits = torch.log_softmax(cond.float(), dim=-1)
        return truncate(logits.double().exp(), options.truncation)


def _passes(options: M2D2MOptions) -> int:
    """Rows per row in a forward pass: the conditional one, and its null one when guided."""
    return 1 if options.guidance == 0.0 else 2


def _guided_rows(index: Tensor, rows: int, options: M2D2MOptions) -> Tensor:
    """The rows of a group in a condition built by :meth:`PhaseModel._condition`: the group's
    conditional rows, then (when guided) their null rows ``rows`` further on."""
    return index if options.guidance == 0.0 else torch.cat([index, index + rows])


@dataclass(frozen=True)
class _Group:
    """Rows of a phase that one forward pass denoises, and what stays the same over a phase's
    steps: their validity mask, action offsets and text condition (None: recomputed every step),
    already repeated for the null rows when guided and padded to the pass's shape."""

    index: Tensor  # (size,) the rows, then (compiled) repeats of the first up to the bucket
    rows: int  # how many of them are real
    width: int  # the longest real row's length
    padded: int  # the pass's width: ``width``, or its bucket when compiled
    valid: Tensor  # (passes·size, padded)
    offsets: Tensor  # (passes·size, padded, 2)
    condition: Condition | None

    @property
    def real(self) -> Tensor:
        return self.index[: self.rows]


# ------------------------------------------------------------------------------------ the layout
@dataclass(frozen=True)
class Row:
    """A row of a phase's batch: which request, which of its stream's tokens, which condition, and
    the lengths of the actions it holds in order (their offsets are the denoiser's ``action``
    positions)."""

    request: int
    stream: slice
    condition: list[str]
    actions: list[int]

    @property
    def length(self) -> int:
        return self.stream.stop - self.stream.start


@dataclass(frozen=True)
class Phase:
    """One phase of Algorithm 1: its reverse jumps (t, s) and the rows it lays the streams out as,
    a batch (rows, width) padded to the longest row. Where the tokens sit in the batch is an index
    tensor built once from the rows' lengths (host integers): a step gathers and scatters through
    it, where a boolean mask would make the host read the data (a device sync) at every step."""

    jumps: list[tuple[int, int]]
    rows: list[Row]
    cells: Tensor  # (N,) each stream token's flat position in the batch, the streams in order
    valid: Tensor  # (rows, width) bool: the real positions
    offsets: Tensor  # (rows, width, 2): each position's distance from its action's ends

    @classmethod
    def of(cls, jumps: list[tuple[int, int]], rows: list[Row], device: torch.device) -> Phase:
        """The phase of ``rows``, which must hold the streams in order, each token once."""
        lengths = [row.length for row in rows]
        width = max(lengths)
        cells = [i * width + k for i, n in enumerate(lengths) for k in range(n)]
        valid = torch.arange(width)[None, :] < torch.tensor(lengths)[:, None]
        return cls(
            jumps,
            rows,
            torch.tensor(cells).to(device, non_blocking=True),
            valid.to(device, non_blocking=True),
            action_offsets([row.actions for row in rows], width, device),
        )

    @property
    def width(self) -> int:
        return self.valid.shape[1]

    @property
    def groups(self) -> list[list[int]]:
        """The rows of each forward pass: rows of similar length (:func:`length_groups`)."""
        return length_groups([row.length for row in self.rows])

    def batch(self, z: Tensor, fill: int) -> Tensor:
        """The streams' tokens ``z`` (N,) as the batch (rows, width), ``fill`` past each row's end."""
        batch = torch.full((len(self.rows) * self.width,), fill, dtype=z.dtype, device=z.device)
        return batch.index_put_((self.cells,), z).view(len(self.rows), self.width)

    def tokens(self, batch: Tensor) -> Tensor:
        """A batch's values (rows, width, ...) at the streams' tokens, in stream order (N, ...)."""
        return batch.flatten(0, 1)[self.cells]


@dataclass(frozen=True)
class RowLayout:
    """Where every token of a batch of requests is, through all of Algorithm 1: the requests'
    streams one after another (``sizes`` tokens each), the tokens kept in them (:data:`FREE`
    where sampled), the tokens neighbouring actions share under handshake, and the phases, each
    with its jumps and its rows (TPS's joint rows then one row per action; one phase for the
    other methods). Built on the host from the requests, sent to the device once."""

    lengths: list[list[int]]  # each request's actions' lengths
    sizes: list[int]  # each request's stream length
    overlap: int  # tokens each later action's row shares with the row before (handshake)
    kept: Tensor  # (N,)
    phases: list[Phase]
    shared: _Shared | None

    @classmethod
    def of(cls, requests: list[TokenRequest], options: M2D2MOptions, steps: int, device: torch.device) -> RowLayout:
        """The layout of ``requests`` under ``options`` for a schedule of ``steps`` steps."""
        overlap = options.handshake if options.method == "handshake" else 0
        joint_until = switch_step(options.ts, steps) if options.method == "tps" else steps
        joint, independent = timesteps(steps, options.steps, joint_until)
        phases = [
            Phase.of(jumps, rows, device)
            for jumps, rows in ((joint, _joint_rows(requests)), (independent, _action_rows(requests, overlap)))
            if jumps
        ]
        return cls(
            [list(r.lengths) for r in requests],
            [sum(r.lengths) + overlap * (len(r.lengths) - 1) for r in requests],
            overlap,
            torch.cat([_kept_stream(r, overlap) for r in requests]).to(device, non_blocking=True),
            phases,
            _Shared.of(requests, overlap, device),
        )

    def prior(self, schedule: TransitionSchedule, generators: list[torch.Generator]) -> Tensor:
        """z_T of every stream, each drawn with its request's generator."""
        return torch.cat([schedule.sample_prior((n,), generator=g) for n, g in zip(self.sizes, generators)])

    def uniforms(self, generators: list[torch.Generator]) -> Tensor:
        """One uniform per token of every stream, each request's from its own generator."""
        device = self.kept.device
        return torch.cat(
            [torch.rand(n, generator=g, dtype=torch.float64, device=device) for n, g in zip(self.sizes, generators)]
        )

    def blend(self, x0: Tensor) -> Tensor:
        """``x0`` (N, K) with the shared tokens' probabilities blended (handshake; in place)."""
        if self.shared is not None:
            self.shared.blend(x0)
        return x0

    def settle(self, z: Tensor) -> Tensor:
        """Drawn tokens ``z`` (N,) with the kept tokens in place and the shared tokens copied."""
        z = torch.where(self.kept >= 0, self.kept, z)
        if self.shared is not None:
            self.shared.copy(z)
        return z

    def split(self, z: Tensor) -> list[list[Tensor]]:
        """Each request's tokens, one tensor per action, the shared copies dropped."""
        return [
            _split_actions(stream, lengths, self.overlap) for stream, lengths in zip(z.split(self.sizes), self.lengths)
        ]


@dataclass(frozen=True)
class _Shared:
    """The tokens neighbouring actions share under handshake: the last H tokens of each earlier
    action's row and the first H of the next, adjacent in the stream, as (pairs, H) positions, and
    the blend's ramp a = 0, 1/H, …, (H−1)/H. Pairs never overlap (every action is at least H
    tokens long), so all are blended and copied at once."""

    earlier: Tensor
    later: Tensor
    ramp: Tensor  # (H, 1)

    @classmethod
    def of(cls, requests: list[TokenRequest], overlap: int, device: torch.device) -> _Shared | None:
        starts, offset = [], 0
        for request in requests:
            rows = _extended_lengths(request.lengths, overlap)
            starts.extend(offset + start for start in list(accumulate(rows))[:-1])
            offset += sum(rows)
        if not overlap or not starts:
            return None
        later = (torch.tensor(starts)[:, None] + torch.arange(overlap)).to(device, non_blocking=True)
        ramp = (torch.arange(overlap, dtype=torch.float64, device=device) / overlap)[:, None]
        return cls(later - overlap, later, ramp)

    def blend(self, x0: Tensor) -> None:
        """Both neighbours get (1 − a)·earlier + a·later on the shared tokens (in place)."""
        blended = (1 - self.ramp) * x0[self.earlier] + self.ramp * x0[self.later]
        x0[self.earlier] = blended
        x0[self.later] = blended

    def copy(self, z: Tensor) -> None:
        """The later row's shared tokens become the earlier row's draws (in place)."""
        z[self.later] = z[self.earlier]


def _joint_rows(requests: list[TokenRequest]) -> list[Row]:
    """One row per request: its whole stream, its actions' sentences concatenated in order."""
    return [
        Row(i, slice(0, sum(r.lengths)), [s for sentences in r.actions for s in sentences], list(r.lengths))
        for i, r in enumerate(requests)
    ]


def _extended_lengths(lengths: list[int], overlap: int) -> list[int]:
    """Row lengths under handshake: every action after the first also holds the shared tokens."""
    return [n + (overlap if i else 0) for i, n in enumerate(lengths)]


def _action_rows(requests: list[TokenRequest], overlap: int) -> list[Row]:
    """One row per action of every request, in order, each with its own sentences."""
    rows = []
    for i, r in enumerate(requests):
        start = 0
        for sentences, n in zip(r.actions, _extended_lengths(r.lengths, overlap)):
            rows.append(Row(i, slice(start, start + n), sentences, [n]))
            start += n
    return rows


def _kept_stream(request: TokenRequest, overlap: int) -> Tensor:
    """``given`` laid out as the request's stream (shared tokens repeated under handshake)."""
    total = sum(request.lengths)
    given = torch.full((total,), FREE, dtype=torch.long) if request.given is None else request.given.long().cpu()
    if overlap:
        pieces, start = [], 0
        for i, n in enumerate(request.lengths):
            if i:
                pieces.append(given[start - overlap : start])
            pieces.append(given[start : start + n])
            start += n
        given = torch.cat(pieces)
    return given


def _split_actions(stream: Tensor, lengths: list[int], overlap: int) -> list[Tensor]:
    """Each action's tokens from a request's stream, the shared copies dropped."""
    pieces, start = [], 0
    for i, n in enumerate(lengths):
        start += overlap if i else 0
        pieces.append(stream[start : start + n].clone())
        start += n
    return pieces


def _shortened(request: TokenRequest, window: int) -> TokenRequest:
    """The request with every action after the first ``window`` tokens shorter (at least 1 left)."""
    if request.given is not None:
        raise ValueError("editing with given tokens is not supported by the slerp baseline")
    lengths = [n if i == 0 else max(1, n - window) for i, n in enumerate(request.lengths)]
    return TokenRequest(request.actions, lengths, request.seed)
