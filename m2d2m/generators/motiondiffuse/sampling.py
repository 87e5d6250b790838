"""MotionDiffuse's reverse process with its fine-grained control (Zhang et al. 2022, §3.5): every
request is a set of *terms*, a sentence over some frames and some feature dimensions of the
sequence, whose noise estimates are combined at every denoising step.

- **Time-varied control** (eq. 11): one term per interval, its own sentence on its own frames
  (intervals may overlap); each ε_i is estimated on the interval alone and padded to the whole
  length. **Body-part control** (eq. 10): one term per part over every frame, its ε_i kept on the
  part's dimensions M_i (:mod:`m2d2m.motion.representation.body_parts`).
- **Combination.** ε̄ = Σ_i pad(ε_i)·M_i, divided, frame by frame and dimension by dimension, by the
  number of terms covering it. Where the terms tile the sequence (the paper's intervals and parts)
  every count is 1 and this is the paper's sum; where intervals overlap it is their mean, since a
  sum would double the noise estimate there (ours).
- **Correction** λ·∇_{x_t} Σ_{i≠j} ‖ε_i − ε_j‖ (eqs. 10 and 11), the gradient taken through the
  network with respect to the noisy motion, as in classifier guidance: adding it to ε̄ moves x_{t−1}
  along −∇, towards terms that agree. Each difference is taken where both terms are defined (the
  frames both intervals cover; for parts, the whole sequence): beyond that a padded zero would
  compare a prediction with nothing. λ = 0 skips the backward pass.
- **Editing** (``keep``): the kept entries of x_{t−1} are replaced by q(x_{t−1} | x_0) of the kept
  motion at every step, and by the kept motion itself at the end (replacement inpainting).

A step of :func:`sample` is the model's estimate, ε̄ of the terms (eqs. 10–11), then the
process's step (ancestral or DDIM), then, when editing, the replacement.

Each request draws its noise from its own generator seeded with its seed, on the CPU, so its result
does not depend on the other requests in the batch nor on the device. A step reads nothing back on
the host (tests/test_host_syncs_models.py): the layout is checked on the host before the first
step, and each step's noise reaches a GPU through pinned memory, so the host draws the next step's
noise while the device still computes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from m2d2m.networks.motiondiffuse_transformer import EncodedText, MotionDiffuseTransformer
from m2d2m.processes.gaussian_diffusion import GaussianDiffusion


@dataclass(frozen=True)
class Term:
    """One noise estimate: ``sentence`` over frames [start, end) and the dimensions ``dims`` (D,)
    bool (None: all of them)."""

    sentence: str
    start: int
    end: int
    dims: np.ndarray | None = None


@dataclass(frozen=True)
class FeatureRequest:
    """One sequence to sample: its length, its terms, its seed, and optionally normalised features
    (frames, D) to keep where ``keep_mask`` (frames, D) is True."""

    frames: int
    terms: tuple[Term, ...]
    seed: int
    keep: torch.Tensor | None = None
    keep_mask: torch.Tensor | None = None


# one reverse step: (x_t, t, ε̄, noise) → x_{t−1}
Step = Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


GROUP = 32  # terms per network call: terms sorted by length, so each call pads little


class Layout:
    """Where every term of a batch of requests reads and writes in the padded motions (B, F, D):
    gather indices into the flattened frames, the term masks, the coverage counts, and the pairs
    of terms of one request that share frames and dimensions (the correction's). Laid out and
    checked on the host, from the requests alone, and copied to the device once."""

    def __init__(
        self, requests: Sequence[FeatureRequest], feature_dim: int, max_term: int, device: torch.device
    ) -> None:
        self.frames = max(request.frames for request in requests)
        self.batch, self.feature_dim = len(requests), feature_dim
        terms = [(b, term) for b, request in enumerate(requests) for term in request.terms]
        self.sentences = [term.sentence for _, term in terms]
        lengths = [term.end - term.start for _, term in terms]
        longest = max(lengths)
        if longest > max_term:
            raise ValueError(f"MotionDiffuse generates at most {max_term} frames per action; {longest} were asked for")
        self.width = longest
        dims = np.stack([_dims_of(term, feature_dim) for _, term in terms])  # (K, D) bool
        gather = torch.zeros(len(terms), longest, dtype=torch.long)
        coverage = np.zeros((self.batch, self.frames, feature_dim), dtype=np.float32)
        for k, (b, term) in enumerate(terms):
            if not 0 <= term.start < term.end <= requests[b].frames:
                raise ValueError(
                    f"a term's frames [{term.start}, {term.end}) lie outside the sequence's {requests[b].frames}"
                )
            gather[k, : lengths[k]] = b * self.frames + torch.arange(term.start, term.end)
            coverage[b, term.start : term.end] += dims[k]
        if any(not (coverage[b, : request.frames] > 0).all() for b, request in enumerate(requests)):
            raise ValueError("the terms leave some frames or body parts of a sequence without a sentence")
        by_length = sorted(range(len(terms)), key=lambda k: -lengths[k])
        groups = [by_length[i : i + GROUP] for i in range(0, len(terms), GROUP)]
        self.groups = [(torch.tensor(rows).to(device, non_blocking=True), lengths[rows[0]]) for rows in groups]
        self.order = torch.argsort(torch.tensor([k for rows in groups for k in rows])).to(device, non_blocking=True)
        self.lengths = torch.tensor(lengths).to(device, non_blocking=True)
        self.valid = (torch.arange(longest)[None, :] < torch.tensor(lengths)[:, None]).to(device, non_blocking=True)
        self.gather = gather.to(device, non_blocking=True)
        self.dims = torch.from_numpy(dims.astype(np.float32)).to(device, non_blocking=True)
        self.coverage = torch.from_numpy(coverage).clamp(min=1.0).to(device, non_blocking=True)
        self._pairs(terms, dims, device)

    def _spread(self, values: torch.Tensor) -> torch.Tensor:
        """Per-term values (K, W, D) zeroed off each term's frames and dimensions."""
        return values * self.valid[:, :, None] * self.dims[:, None, :]

    def _pairs(self, terms: list[tuple[int, Term]], dims: np.ndarray, device: torch.device) -> None:
        """For each pair of terms of one request sharing frames and dimensions (``dims``: (K, D)
        bool): the flat indices of the shared frames in each term's estimate and the shared
        dimensions."""
        first, second, shared_dims = [], [], []
        for i, (b, a) in enumerate(terms):
            for j in range(i + 1, len(terms)):
                other_b, other = terms[j]
                start, end = max(a.start, other.start), min(a.end, other.end)
                shared = dims[i] & dims[j]
                if other_b != b or start >= end or not shared.any():
                    continue
                frames = torch.arange(start, end)
                first.append(i * self.width + frames - a.start)
                second.append(j * self.width + frames - other.start)
                shared_dims.append(shared)
        self.pair_count = len(first)
        if first:
            pad = torch.nn.utils.rnn.pad_sequence
            self.pair_first = pad(first, batch_first=True, padding_value=-1).to(device, non_blocking=True)
            self.pair_second = pad(second, batch_first=True, padding_value=-1).to(device, non_blocking=True)
            self.pair_dims = torch.from_numpy(np.stack(shared_dims).astype(np.float32)).to(device, non_blocking=True)

    def terms_of(self, x: torch.Tensor) -> torch.Tensor:
        """Each term's frames of the padded motions x (B, F, D): (K, W, D), zero past its length."""
        return x.reshape(-1, self.feature_dim)[self.gather] * self.valid[:, :, None]

    def estimate(
        self, network: MotionDiffuseTransformer, x: torch.Tensor, t: torch.Tensor, text: EncodedText
    ) -> torch.Tensor:
        """Every term's ε_θ (K, W, D) on its frames of x (B, F, D), zero past its length. Terms go
        through the network in groups of similar length, each padded to its own longest: padding
        never changes a valid frame's estimate (the network masks it), it only costs time. The
        estimates are float32 whatever the network ran in (bf16 under a GPU's autocast): the
        diffusion's arithmetic on x_t keeps full precision."""
        terms = self.terms_of(x)
        estimates = [
            network(terms[rows, :width], t[rows], self.lengths[rows], text.take(rows)).float()
            for rows, width in self.groups
        ]
        padded = [torch.nn.functional.pad(eps, (0, 0, 0, self.width - eps.shape[1])) for eps in estimates]
        return torch.cat(padded)[self.order] * self.valid[:, :, None]

    def combine(self, eps: torch.Tensor) -> torch.Tensor:
        """ε̄ (B, F, D) from the terms' estimates (K, W, D): each term on its frames and dimensions,
        divided by the coverage."""
        total = torch.zeros(self.batch * self.frames, self.feature_dim, dtype=eps.dtype, device=eps.device)
        total = total.index_add(0, self.gather.flatten(), self._spread(eps).flatten(0, 1))
        return total.view(self.batch, self.frames, self.feature_dim) / self.coverage

    def disagreement(self, eps: torch.Tensor) -> torch.Tensor:
        """Σ_{i≠j} ‖ε_i − ε_j‖ over every pair sharing frames and dimensions, both orders (eqs. 10, 11)."""
        if not self.pair_count:
            return eps.sum() * 0.0
        flat = eps.reshape(-1, self.feature_dim)
        valid = (self.pair_first >= 0)[:, :, None]
        difference = (flat[self.pair_first.clamp(min=0)] - flat[self.pair_second.clamp(min=0)]) * valid
        difference = difference * self.pair_dims[:, None, :]
        return 2.0 * torch.linalg.vector_norm(difference.flatten(1), dim=1).sum()


def _dims_of(term: Term, feature_dim: int) -> np.ndarray:
    """(D,) bool: the feature dimensions a term speaks for."""
    return np.ones(feature_dim, dtype=bool) if term.dims is None else np.asarray(term.dims, dtype=bool)


def _pad(rows: Sequence[torch.Tensor], frames: int) -> torch.Tensor:
    return torch.stack([torch.nn.functional.pad(row, (0, 0, 0, frames - len(row))) for row in rows])


def _to_device(host: torch.Tensor, device: torch.device) -> torch.Tensor:
    """A tensor made on the host, on ``device``. To a GPU through pinned memory: a copy from
    pageable memory waits for the device's queue (CUDA runtime API, "API synchronization
    behavior"), one from pinned memory with ``non_blocking`` does not, and PyTorch's caching host
    allocator keeps the pinned block until the copy is done (PyTorch tutorial, "A guide on good
    usage of non_blocking and pin_memory()")."""
    if device.type != "cuda":
        return host.to(device)
    return host.pin_memory().to(device, non_blocking=True)


class _Noise:
    """Gaussian noise (B, F, D) for every request, each drawn from its own generator on the CPU
    (zeros for a request without one), so that no request depends on the batch or the device."""

    def __init__(
        self,
        requests: Sequence[FeatureRequest],
        generators: Sequence[torch.Generator | None],
        layout: Layout,
        device: torch.device,
    ) -> None:
        self.requests, self.generators, self.layout, self.device = requests, generators, layout, device

    def draw(self) -> torch.Tensor:
        dim = self.layout.feature_dim
        rows = [
            torch.zeros(r.frames, dim) if g is None else torch.randn(r.frames, dim, generator=g)
            for r, g in zip(self.requests, self.generators)
        ]
        return _to_device(_pad(rows, self.layout.frames), self.device)


class _Replacement:
    """Editing by replacement: after every step the kept entries of x_{t−1} become a draw of
    q(x_{t−1} | x_0) of the kept motion, and the kept motion itself after the last. Its noise comes
    from a second stream per request, drawn only by requests that keep something."""

    def __init__(
        self, requests: Sequence[FeatureRequest], layout: Layout, process: GaussianDiffusion, device: torch.device
    ) -> None:
        dim = layout.feature_dim
        kept = [torch.zeros(r.frames, dim) if r.keep is None else r.keep for r in requests]
        masks = [torch.zeros(r.frames, dim, dtype=torch.bool) if r.keep is None else r.keep_mask for r in requests]
        self.keep = _to_device(_pad(kept, layout.frames), device)
        self.mask = _to_device(_pad(masks, layout.frames).bool(), device)
        self.process = process
        generators = [None if r.keep is None else torch.Generator().manual_seed(_keep_seed(r.seed)) for r in requests]
        self.noise = _Noise(requests, generators, layout, device)

    def __call__(self, x: torch.Tensor, t: torch.Tensor, index: int) -> torch.Tensor:
        """x_{t−1} (the step ``index``'s result) with the kept entries replaced."""
        known = self.keep if index == 0 else self.process.q_sample(self.keep, t - 1, self.noise.draw())
        return torch.where(self.mask, known, x)


def _keep_seed(seed: int) -> int:
    """The seed of a request's second stream, the kept motion's noise."""
    return int(np.random.SeedSequence([int(seed), 1]).generate_state(1)[0])


class _CombinedNoise:
    """``model(x_t, t)`` of the loop: ε̄, every term's noise estimate combined on its frames and
    dimensions (eqs. 10, 11), plus the correction λ·∇_{x_t} Σ_{i≠j} ‖ε_i − ε_j‖. A network that
    predicts x_0 has each term's estimate turned into the ε it implies first, so the combination
    and the correction work on ε as the paper's do."""

    def __init__(
        self,
        network: MotionDiffuseTransformer,
        text: EncodedText,
        layout: Layout,
        process: GaussianDiffusion,
        correction: float,
        prediction: str,
    ) -> None:
        self.network, self.text, self.layout, self.process = network, text, layout, process
        self.correction, self.prediction = correction, prediction
        self.guided = correction > 0 and layout.pair_count > 0

    def __call__(self, x: torch.Tensor, index: int) -> torch.Tensor:
        layout, guided, device = self.layout, self.guided, x.device
        network_t = self.process.network_steps(
            torch.full((len(layout.sentences),), index, dtype=torch.long, device=device)
        )
        with torch.enable_grad() if guided else torch.no_grad():
            x_in = x.detach().requires_grad_(guided)
            eps = layout.estimate(self.network, x_in, network_t, self.text)
            if self.prediction == "x0":
                term_t = torch.full((len(eps),), index, dtype=torch.long, device=device)
                eps = self.process.predict_eps(layout.terms_of(x_in), term_t, eps) * layout.valid[:, :, None]
            combined = layout.combine(eps)
            if guided:
                (gradient,) = torch.autograd.grad(layout.disagreement(eps), x_in)
                combined = combined + self.correction * gradient
        return combined.detach()


def sample(
    network: MotionDiffuseTransformer,
    text: EncodedText,
    requests: Sequence[FeatureRequest],
    process: GaussianDiffusion,
    step: Step,
    correction: float,
    progress: Callable[[float], None] | None = None,
    prediction: str = "epsilon",
) -> list[torch.Tensor]:
    """Each request's normalised motion (frames, D), denoised from N(0, I) through every step of
    ``process`` with ``step`` (ancestral or DDIM); ``text`` holds one encoded sentence per term, in
    the order of the requests and their terms; ``correction`` is λ; ``prediction`` what the
    network predicts (ε or x_0)."""
    device = text.sentence.device
    layout = Layout(requests, network.config.feature_dim, network.config.max_frames, device)
    noise = _Noise(requests, [torch.Generator().manual_seed(int(r.seed)) for r in requests], layout, device)
    model = _CombinedNoise(network, text, layout, process, correction, prediction)
    replace = _Replacement(requests, layout, process, device) if any(r.keep is not None for r in requests) else None
    x = noise.draw()  # x_T ~ N(0, I)
    total = process.num_steps
    for index in reversed(range(total)):
        t = torch.full((layout.batch,), index, dtype=torch.long, device=device)
        x = step(x, t, model(x, index), noise.draw())  # x_{t−1} ~ p_θ(x_{t−1} | x_t) with ε̄ (eq. 5)
        if replace is not None:
            x = replace(x, t, index)
        if progress is not None and (index % max(1, total // 100) == 0):
            progress((total - index) / total)
    return [x[b, : request.frames].detach() for b, request in enumerate(requests)]
