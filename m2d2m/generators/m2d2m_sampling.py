"""Token samplers of M2D2M: single actions, Two-Phase Sampling (paper Algorithm 1), the paper's
multi-motion baselines on the same model, and editing by fixed tokens.

Every sampler runs the same reverse step — guided x0 probabilities (classifier-free guidance s,
VQ-Diffusion's truncation r), the posterior p(z_{t−1} | z_t) of the transition schedule, one
categorical draw per position — over a batch of *rows*. What differs is how a request's actions
are laid out as rows:

- ``tps``: for t = T … T_s+1 one row per request, its actions concatenated and its conditions
  concatenated (joint phase); for t = T_s … 1 one row per action (independent phase).
- ``independent``: one row per action for all t (the paper's T2M-GPT baseline: tokens sampled
  alone, concatenated before decoding). It is ``tps`` with T_s = T.
- ``handshake``: one row per action, each action after the first extended by H tokens that it shares
  with the end of the previous one; at every step the overlapping x0 probabilities are blended
  with a linear ramp and the drawn tokens copied, so neighbours share one transition (DoubleTake's
  first take, priorMDM/priorMDM ``sample/double_take.py``, in token space).
- ``slerp``: one row per action, every action after the first shortened by the transition window;
  the motion-level gap filling is :func:`m2d2m.motion.joining.bridge` (TEACH's SLERP baseline).

Randomness is per request: each request has its own generator and draws, at every step, one
uniform per position of its actions in order, whatever the rows look like. Hence a request's
result does not depend on what else is in the batch, and ``tps`` with T_s = T reproduces
``independent`` draw for draw.

Rows of very different lengths are not padded to the longest: the denoiser runs once per group of
rows of similar length (:func:`length_groups`), which on test sets of 10- to 50-token actions halves
the work of a step. Padded positions never reach the posterior. What does not change from step to
step is computed once per phase: the text's features and every block's cross-attention keys and
values (:class:`m2d2m.networks.m2d2m_denoiser.Condition`), for the conditional and the null rows
of classifier-free guidance together, and where the real positions are, as index tensors built
from the lengths the host knows. A step only gathers and scatters through them, so on a GPU it
never waits for the device (``tests/test_host_syncs.py``). With the ``compile`` option the
denoiser's passes run compiled at bucketed shapes (:mod:`m2d2m.generators.m2d2m_compiled`).

Fewer steps than the schedule's T (``steps``) jump from t to s < t with the exact posterior
q(z_s | z_t, z0) (:meth:`TransitionSchedule.posterior_probs`; VQ-Diffusion's fast sampling
approximates that jump by a one-step posterior at s), on a grid that keeps T_s one of its points
(:func:`timesteps`); at ``steps`` = T it is the full sampler draw for draw.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import accumulate

import torch
import torch.nn.functional as F
from torch import Tensor

from m2d2m.generators.m2d2m_compiled import CompiledDenoise, bucket, compiles
from m2d2m.generators.m2d2m_options import M2D2MOptions
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


@dataclass
class _Row:
    """A row of the batch: which request, which of its stream positions, which condition, and the
    lengths of the actions it holds in order (their offsets are the denoiser's ``action`` positions)."""

    request: int
    stream: slice  # positions in the request's per-step uniform stream
    condition: list[str]
    actions: list[int]


@dataclass
class _Layout:
    rows: list[_Row]
    overlap: int = 0  # tokens each later action's row shares with the row before (handshake)
    length: int = field(init=False)

    def __post_init__(self) -> None:
        self.length = max(row.stream.stop - row.stream.start for row in self.rows)


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


def categorical(probs: Tensor, uniforms: Tensor) -> Tensor:
    """Inverse-CDF draw over the last dimension with given uniforms in [0, 1).

    Counting the states whose CDF stays at or below u·total never picks a zero-probability state;
    a row with no mass at all gets the last state (the mask), which the caller treats as undecided.
    """
    cdf = probs.cumsum(dim=-1)
    chosen = (cdf <= uniforms.unsqueeze(-1).to(cdf.dtype) * cdf[..., -1:]).sum(dim=-1)
    return chosen.clamp_max(probs.shape[-1] - 1)


class TokenSampler:
    """Reverse diffusion over motion tokens for a denoiser, its text encoder and its schedule.

    Works on the device the denoiser is on; the schedule is moved there. An η in the options
    builds the dynamic schedule's matrices for that η once (a few hundred milliseconds at K = 512, T = 100).
    With the ``compile`` option the denoiser runs through ``torch.compile`` at bucketed shapes
    (:mod:`m2d2m.generators.m2d2m_compiled`), compiled once per shape for the sampler's life.
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
        self._compiled: CompiledDenoise | None = None

    @property
    def device(self) -> torch.device:
        return next(self.denoiser.parameters()).device

    def _schedule(self, eta: float | None) -> TransitionSchedule:
        """The schedule at ``eta`` on the model's device, built once per η (with the jumps it has
        taken cached in it); a ``uniform`` schedule has no η to change."""
        schedule = self.schedule
        if eta is not None and schedule.config.kind == "dynamic" and float(eta) != schedule.config.eta:
            if float(eta) not in self._at_eta:
                self._at_eta[float(eta)] = schedule.with_eta(eta)
            schedule = self._at_eta[float(eta)]
        return schedule.to(self.device) if schedule.device != self.device else schedule

    def _forward(self, options: M2D2MOptions) -> tuple[Callable[..., Tensor], bool]:
        """The denoiser's forward pass the options ask for, and whether it is compiled (then the
        passes are padded to buckets)."""
        if not compiles(options.compile, self.device):
            return self.denoiser.denoise, False
        if self._compiled is None or self._compiled.denoiser is not self.denoiser:
            self._compiled = CompiledDenoise(self.denoiser)
        return self._compiled, self._compiled.compiled

    # ------------------------------------------------------------------------------------- public
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
            return self._run(requests, options, schedule, progress)
        finally:
            self.denoiser.train(was_training)
            self.text_encoder.train(was_training)

    # ----------------------------------------------------------------------------------- internals
    def _run(
        self,
        requests: list[TokenRequest],
        options: M2D2MOptions,
        schedule: TransitionSchedule,
        progress: Callable[[int], None] | None,
    ) -> list[list[Tensor]]:
        device = self.device
        generators = [torch.Generator(device=device).manual_seed(int(r.seed)) for r in requests]
        overlap = options.handshake if options.method == "handshake" else 0
        sizes = [sum(r.lengths) + overlap * (len(r.lengths) - 1) for r in requests]
        # z_T, laid out as each request's stream (for handshake, the shared tokens appear twice)
        prior = [schedule.sample_prior((n,), generator=g) for n, g in zip(sizes, generators)]
        given = [_given_stream(r, overlap, device) for r in requests]
        state = [torch.where(g >= 0, g, z) for g, z in zip(given, prior)]
        if overlap:
            state = [_copy_shared(z, _extended_lengths(r.lengths, overlap), overlap) for z, r in zip(state, requests)]
        stream, kept = torch.cat(state), torch.cat(given)  # every request's stream, one after another

        joint_until = switch_step(options.ts, schedule.steps) if options.method == "tps" else schedule.steps
        joint, independent = timesteps(schedule.steps, options.steps, joint_until)
        for jumps, layout in ((joint, _joint_layout(requests)), (independent, _action_layout(requests, overlap))):
            if jumps:
                stream = self._denoise(layout, stream, kept, generators, sizes, jumps, schedule, options, progress)
        return [_split_actions(z, r.lengths, overlap) for z, r in zip(stream.split(sizes), requests)]

    def _denoise(
        self,
        layout: _Layout,
        stream: Tensor,
        given: Tensor,
        generators: list[torch.Generator],
        sizes: list[int],
        jumps: list[tuple[int, int]],
        schedule: TransitionSchedule,
        options: M2D2MOptions,
        progress: Callable[[int], None] | None,
    ) -> Tensor:
        """Take the reverse ``jumps`` (t, s) on the rows of ``layout``. ``stream`` and ``given`` hold
        every request's stream, one after another (``sizes`` long each); returns the stream after
        the last jump.

        Where the rows' real positions are, which rows share a forward pass and which tokens
        neighbours share is laid out once, as index tensors; a step gathers and scatters through
        them, so nothing in the loop makes the host wait for the device."""
        device, mask, codes = self.device, schedule.mask_index, schedule.num_codes
        denoise, compiled = self._forward(options)
        rows, width = len(layout.rows), layout.length
        positions = _Positions.of(layout, sizes, device)
        shared = _Shared.of(layout, device)
        text, text_mask = self._text(layout, compiled)
        groups = self._groups(layout, text, text_mask, options, compiled)
        fixed = given[positions.streams]
        z = positions.scatter(stream[positions.streams], rows, width, mask)
        for t, s in jumps:
            x0 = torch.zeros(rows, width, codes, dtype=torch.float64, device=device)
            for group in groups:
                x0[group.real, : group.width] = self._x0(z, group, t, text, text_mask, options, denoise)
            if shared is not None:
                shared.blend(x0)
            x0 = x0.view(-1, codes)[positions.cells]
            probs = schedule.posterior_probs(z.view(-1)[positions.cells], x0, t, s, validate=False)
            uniforms = torch.cat(
                [torch.rand(n, generator=g, dtype=torch.float64, device=device) for n, g in zip(sizes, generators)]
            )
            drawn = categorical(probs, uniforms[positions.streams])
            if s == 0:  # no mask may survive the last step: a dead position takes the most likely code
                drawn = torch.where(drawn == mask, x0.argmax(dim=-1), drawn)
            z = positions.scatter(torch.where(fixed >= 0, fixed, drawn), rows, width, mask)
            if shared is not None:
                shared.copy(z)
            if progress is not None:
                progress(s)
        return stream.index_put((positions.streams,), z.view(-1)[positions.cells])

    def _text(self, layout: _Layout, compiled: bool) -> tuple[Tensor, Tensor]:
        """The rows' text features and mask; a row whose sentences are all empty asks for no text
        and gets the null condition of classifier-free guidance. Compiled, the text is padded to a
        bucket of tokens (masked keys: nothing changes at the real ones)."""
        text, text_mask = encode_actions(self.text_encoder, [row.condition for row in layout.rows])
        unconditional = [not any(s.strip() for s in row.condition) for row in layout.rows]
        if any(unconditional):
            rows = torch.tensor(unconditional).to(text.device, non_blocking=True)
            text, text_mask = self.denoiser.nullify(text, text_mask, rows)
        if compiled:
            extra = bucket(text.shape[1], smallest=8) - text.shape[1]
            text, text_mask = F.pad(text, (0, 0, 0, extra)), F.pad(text_mask, (0, extra))
        return text, text_mask

    def _condition(self, text: Tensor, text_mask: Tensor, options: M2D2MOptions) -> Condition:
        """The denoiser's condition of the rows, followed, when guided, by as many null rows."""
        if options.guidance == 0.0:
            return self.denoiser.condition(text, text_mask)
        every = torch.ones(text.shape[0], dtype=torch.bool, device=text.device)
        null_text, null_mask = self.denoiser.nullify(text, text_mask, every)
        return self.denoiser.condition(torch.cat([text, null_text]), torch.cat([text_mask, null_mask]))

    def _groups(
        self, layout: _Layout, text: Tensor, text_mask: Tensor, options: M2D2MOptions, compiled: bool
    ) -> list[_Group]:
        """The forward passes of a step (:func:`length_groups`) with what they keep over the phase;
        compiled, each is padded to a bucket of rows and of tokens."""
        device = self.device
        lengths = [row.stream.stop - row.stream.start for row in layout.rows]
        valid = (torch.arange(layout.length)[None, :] < torch.tensor(lengths)[:, None]).to(device, non_blocking=True)
        offsets = action_offsets([row.actions for row in layout.rows], layout.length, device)
        condition = self._condition(text, text_mask, options) if self.reuse_condition else None
        passes = _passes(options)
        groups = []
        for members in length_groups(lengths):
            width = lengths[members[0]]
            size, padded = (bucket(len(members)), bucket(width, smallest=8)) if compiled else (len(members), width)
            index = torch.tensor(members + members[:1] * (size - len(members))).to(device, non_blocking=True)
            groups.append(
                _Group(
                    index,
                    len(members),
                    width,
                    padded,
                    F.pad(valid[index, :width], (0, padded - width)).repeat(passes, 1),
                    F.pad(offsets[index, :width], (0, 0, 0, padded - width)).repeat(passes, 1, 1),
                    None if condition is None else condition.rows(_guided_rows(index, len(layout.rows), options)),
                )
            )
        return groups

    def _x0(
        self,
        z: Tensor,
        group: _Group,
        t: int,
        text: Tensor,
        text_mask: Tensor,
        options: M2D2MOptions,
        denoise: Callable[..., Tensor],
    ) -> Tensor:
        """Guided, truncated p(z0 | z_t) (rows, width, K) in float64 of a group's real rows: one
        forward pass of the conditional and null rows together (``group.condition`` holds both
        when guided)."""
        tokens = z[group.index, : group.width]
        if group.padded > group.width:
            tokens = F.pad(tokens, (0, group.padded - group.width), value=self.denoiser.mask_id)
        condition = group.condition
        if condition is None:
            condition = self._condition(text[group.index], text_mask[group.index], options)
        steps = torch.full((1,), t, dtype=torch.long, device=z.device)  # one t for every row: embedded once
        logits = denoise(tokens.repeat(_passes(options), 1), group.valid, steps, condition, group.offsets)
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
    """The rows of a group in a condition built by :meth:`TokenSampler._condition`: the group's
    conditional rows, then (when guided) their null rows ``rows`` further on."""
    return index if options.guidance == 0.0 else torch.cat([index, index + rows])


@dataclass(frozen=True)
class _Group:
    """Rows of a layout that one forward pass denoises, and what stays the same over a phase's
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


@dataclass(frozen=True)
class _Positions:
    """A layout's real positions as index tensors on the device, built once per phase from the
    rows' lengths (host integers): a step gathers and scatters through them, where a boolean mask
    would make the host read the data (a device sync) at every step."""

    cells: Tensor  # (N,) flat positions in the (rows, width) batch, row by row
    streams: Tensor  # (N,) the same positions in the requests' streams, one after another

    @classmethod
    def of(cls, layout: _Layout, sizes: list[int], device: torch.device) -> _Positions:
        starts = [0, *accumulate(sizes)]
        cells: list[int] = []
        streams: list[int] = []
        for i, row in enumerate(layout.rows):
            n = row.stream.stop - row.stream.start
            cells.extend(range(i * layout.length, i * layout.length + n))
            begin = starts[row.request] + row.stream.start
            streams.extend(range(begin, begin + n))
        return cls(
            torch.tensor(cells).to(device, non_blocking=True), torch.tensor(streams).to(device, non_blocking=True)
        )

    def scatter(self, values: Tensor, rows: int, width: int, fill: int) -> Tensor:
        """(rows, width) holding ``values`` (N,) at the real positions and ``fill`` elsewhere."""
        batch = torch.full((rows * width,), fill, dtype=values.dtype, device=values.device)
        return batch.index_put_((self.cells,), values).view(rows, width)


@dataclass(frozen=True)
class _Shared:
    """The tokens neighbouring actions share under handshake: the last H positions of each earlier
    row and the first H of the next, as (pairs, H) row and column indices, and the blend's ramp
    a = 0, 1/H, …, (H−1)/H. Pairs never overlap (every action is at least H tokens long), so all
    are blended and copied at once."""

    earlier: tuple[Tensor, Tensor]
    later: tuple[Tensor, Tensor]
    ramp: Tensor  # (H, 1)

    @classmethod
    def of(cls, layout: _Layout, device: torch.device) -> _Shared | None:
        pairs = _row_pairs(layout)
        overlap = layout.overlap
        if not overlap or not pairs:
            return None
        columns = torch.arange(overlap)
        earlier_rows = torch.tensor([[earlier] for earlier, _, _ in pairs])
        earlier_columns = torch.tensor([[end - overlap] for _, _, end in pairs]) + columns
        later_rows = torch.tensor([[later] for _, later, _ in pairs])
        index = [x.to(device, non_blocking=True) for x in (earlier_rows, earlier_columns, later_rows, columns[None])]
        ramp = (torch.arange(overlap, dtype=torch.float64, device=device) / overlap)[:, None]
        return cls((index[0], index[1]), (index[2], index[3]), ramp)

    def blend(self, x0: Tensor) -> None:
        """Both neighbours get (1 − a)·earlier + a·later on the shared tokens (in place)."""
        blended = (1 - self.ramp) * x0[self.earlier] + self.ramp * x0[self.later]
        x0[self.earlier] = blended
        x0[self.later] = blended

    def copy(self, z: Tensor) -> None:
        """The later row's shared tokens become the earlier row's draws (in place)."""
        z[self.later] = z[self.earlier]


# --------------------------------------------------------------------------------------- layouts
def _joint_layout(requests: list[TokenRequest]) -> _Layout:
    """One row per request: its whole stream, its actions' sentences concatenated in order."""
    return _Layout(
        [
            _Row(i, slice(0, sum(r.lengths)), [s for sentences in r.actions for s in sentences], list(r.lengths))
            for i, r in enumerate(requests)
        ]
    )


def _extended_lengths(lengths: list[int], overlap: int) -> list[int]:
    """Row lengths under handshake: every action after the first also holds the shared tokens."""
    return [n + (overlap if i else 0) for i, n in enumerate(lengths)]


def _action_layout(requests: list[TokenRequest], overlap: int) -> _Layout:
    """One row per action of every request, in order, each with its own sentences."""
    rows = []
    for i, r in enumerate(requests):
        start = 0
        for sentences, n in zip(r.actions, _extended_lengths(r.lengths, overlap)):
            rows.append(_Row(i, slice(start, start + n), sentences, [n]))
            start += n
    return _Layout(rows, overlap)


def _given_stream(request: TokenRequest, overlap: int, device: torch.device) -> Tensor:
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
    return given.to(device, non_blocking=True)


def _copy_shared(stream: Tensor, lengths: list[int], overlap: int) -> Tensor:
    """A stream whose shared copies (the start of every later action's row) repeat the end of the
    action before."""
    stream = stream.clone()
    start = 0
    for i, n in enumerate(lengths):
        if i:
            stream[start : start + overlap] = stream[start - overlap : start]
        start += n
    return stream


def _row_pairs(layout: _Layout) -> list[tuple[int, int, int]]:
    """(earlier row, later row, earlier row's length) for neighbouring actions of one request."""
    return [
        (i - 1, i, layout.rows[i - 1].stream.stop - layout.rows[i - 1].stream.start)
        for i in range(1, len(layout.rows))
        if layout.rows[i - 1].request == layout.rows[i].request
    ]


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
