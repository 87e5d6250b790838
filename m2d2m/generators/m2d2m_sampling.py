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
of classifier-free guidance together.

Fewer steps than the schedule's T (``steps``) jump from t to s < t with the exact posterior
q(z_s | z_t, z0) (:meth:`TransitionSchedule.posterior_probs`; VQ-Diffusion's fast sampling
approximates that jump by a one-step posterior at s), on a grid that keeps T_s one of its points
(:func:`timesteps`); at ``steps`` = T it is the full sampler draw for draw.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

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
        streams = [sum(r.lengths) + overlap * (len(r.lengths) - 1) for r in requests]
        # z_T, laid out as each request's stream (for handshake, the shared tokens appear twice)
        state = [schedule.sample_prior((n,), generator=g) for n, g in zip(streams, generators)]
        given = [_given_stream(r, overlap, device) for r in requests]
        state = [torch.where(g >= 0, g, z) for g, z in zip(given, state)]
        if overlap:
            state = [_copy_shared(z, _extended_lengths(r.lengths, overlap), overlap) for z, r in zip(state, requests)]

        joint_until = switch_step(options.ts, schedule.steps) if options.method == "tps" else schedule.steps
        joint, independent = timesteps(schedule.steps, options.steps, joint_until)
        for jumps, layout in ((joint, _joint_layout(requests)), (independent, _action_layout(requests, overlap))):
            if jumps:
                state = self._denoise(layout, state, given, generators, jumps, schedule, options, overlap, progress)
        return [_split_actions(z, r.lengths, overlap) for z, r in zip(state, requests)]

    def _denoise(
        self,
        layout: _Layout,
        state: list[Tensor],
        given: list[Tensor],
        generators: list[torch.Generator],
        jumps: list[tuple[int, int]],
        schedule: TransitionSchedule,
        options: M2D2MOptions,
        overlap: int,
        progress: Callable[[int], None] | None,
    ) -> list[Tensor]:
        """Take the reverse ``jumps`` (t, s) on the rows of ``layout``; returns the requests' streams."""
        device, mask, codes = self.device, schedule.mask_index, schedule.num_codes
        rows, width = len(layout.rows), layout.length
        row_lengths = [row.stream.stop - row.stream.start for row in layout.rows]
        lengths = torch.tensor(row_lengths, device=device)
        valid = torch.arange(width, device=device)[None, :] < lengths[:, None]
        offsets = action_offsets([row.actions for row in layout.rows], width, device)
        groups = [(torch.tensor(g, device=device), row_lengths[g[0]]) for g in length_groups(row_lengths)]
        text, text_mask = self._text(layout)
        condition = self._condition(text, text_mask, options) if self.reuse_condition else None
        z = torch.full((rows, width), mask, dtype=torch.long, device=device)
        fixed = torch.full_like(z, FREE)
        for i, row in enumerate(layout.rows):
            n = row.stream.stop - row.stream.start
            z[i, :n] = state[row.request][row.stream]
            fixed[i, :n] = given[row.request][row.stream]
        for t, s in jumps:
            x0 = torch.zeros(rows, width, codes, dtype=torch.float64, device=device)
            for index, n in groups:
                rows_condition = (
                    self._condition(text[index], text_mask[index], options)
                    if condition is None
                    else condition.rows(_guided_rows(index, rows, options))
                )
                x0[index, :n] = self._x0(z[index, :n], valid[index, :n], offsets[index, :n], t, rows_condition, options)
            if overlap:
                x0 = _blend_shared(x0, layout, overlap)
            probs = torch.zeros(rows, width, codes + 1, dtype=torch.float64, device=device)
            probs[valid] = schedule.posterior_probs(z[valid], x0[valid], t, s)
            uniforms = torch.zeros(rows, width, dtype=torch.float64, device=device)
            draws = [
                torch.rand(streams, generator=g, dtype=torch.float64, device=device)
                for streams, g in zip((s.numel() for s in state), generators)
            ]
            for i, row in enumerate(layout.rows):
                uniforms[i, : row.stream.stop - row.stream.start] = draws[row.request][row.stream]
            z = categorical(probs, uniforms)
            if s == 0:  # no mask may survive the last step: a dead row takes the most likely code
                z = torch.where(z == mask, x0.argmax(dim=-1), z)
            z = torch.where(fixed >= 0, fixed, z).masked_fill(~valid, mask)
            if overlap:
                z = _copy_shared_rows(z, layout, overlap)
            if progress is not None:
                progress(s)
        out = [stream.clone() for stream in state]
        for i, row in enumerate(layout.rows):
            out[row.request][row.stream] = z[i, : row.stream.stop - row.stream.start]
        return out

    def _text(self, layout: _Layout) -> tuple[Tensor, Tensor]:
        """The rows' text features and mask; a row whose sentences are all empty asks for no text
        and gets the null condition of classifier-free guidance."""
        text, text_mask = encode_actions(self.text_encoder, [row.condition for row in layout.rows])
        unconditional = torch.tensor([not any(s.strip() for s in row.condition) for row in layout.rows])
        if unconditional.any():
            text, text_mask = self.denoiser.nullify(text, text_mask, unconditional)
        return text, text_mask

    def _condition(self, text: Tensor, text_mask: Tensor, options: M2D2MOptions) -> Condition:
        """The denoiser's condition of the rows, followed, when guided, by as many null rows."""
        if options.guidance == 0.0:
            return self.denoiser.condition(text, text_mask)
        null_text, null_mask = self.denoiser.nullify(text, text_mask, torch.ones(text.shape[0], dtype=torch.bool))
        return self.denoiser.condition(torch.cat([text, null_text]), torch.cat([text_mask, null_mask]))

    def _x0(
        self, z: Tensor, valid: Tensor, offsets: Tensor, t: int, condition: Condition, options: M2D2MOptions
    ) -> Tensor:
        """Guided, truncated p(z0 | z_t) (rows, width, K) in float64: one forward pass of the
        conditional and null rows together (``condition`` holds both when guided)."""
        rows = z.shape[0]
        repeat = 1 if options.guidance == 0.0 else 2
        steps = torch.full((1,), t, dtype=torch.long, device=z.device)  # one t for every row: embedded once
        logits = self.denoiser.denoise(
            z.repeat(repeat, 1), valid.repeat(repeat, 1), steps, condition, offsets.repeat(repeat, 1, 1)
        )
        if repeat == 1:
            logits = torch.log_softmax(logits.float(), dim=-1)
        else:
            logits = guided_logits(logits[:rows], logits[rows:], options.guidance)
        return truncate(logits.double().exp(), options.truncation)


def _guided_rows(index: Tensor, rows: int, options: M2D2MOptions) -> Tensor:
    """The rows of a group in a condition built by :meth:`TokenSampler._condition`: the group's
    conditional rows, then (when guided) their null rows ``rows`` further on."""
    return index if options.guidance == 0.0 else torch.cat([index, index + rows])


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
    return _Layout(rows)


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
    return given.to(device)


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


def _blend_shared(x0: Tensor, layout: _Layout, overlap: int) -> Tensor:
    """Both neighbours get (1 − a)·earlier + a·later on the shared tokens, a = 0, 1/H, …, (H−1)/H."""
    x0 = x0.clone()
    ramp = (torch.arange(overlap, dtype=x0.dtype, device=x0.device) / overlap)[:, None]
    for earlier, later, end in _row_pairs(layout):
        blended = (1 - ramp) * x0[earlier, end - overlap : end] + ramp * x0[later, :overlap]
        x0[earlier, end - overlap : end] = blended
        x0[later, :overlap] = blended
    return x0


def _copy_shared_rows(z: Tensor, layout: _Layout, overlap: int) -> Tensor:
    for earlier, later, end in _row_pairs(layout):
        z[later, :overlap] = z[earlier, end - overlap : end]
    return z


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
