"""Text to motion from a trained checkpoint: the user-facing :class:`Generator` and its MLflow logging.

``Generator.from_checkpoint("latest")`` (or a ``model.pt``, a run directory or name, or an MLflow
run id) loads everything sampling needs. ``generate(prompts)`` splits free-text prompts into
action sentences with the dataset's tagger (as the corpus was split), gives each action a length
(the seconds asked for, or the corpus's median length for the action's verb), samples tokens with
the chosen method and decodes them into a :class:`~m2d2m.motion.Motion`.
"""

from __future__ import annotations

import re
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from m2d2m.checkpoint import Checkpoint, load_checkpoint
from m2d2m.layout import MODEL_FILE, NLP
from m2d2m.motion import Motion
from m2d2m.representation import features_to_joints, joints_to_features
from m2d2m.sampling import FREE, Request, SamplingOptions, TokenSampler
from m2d2m.transitions import slerp_join
from orchestration.errors import UserError
from orchestration.runs import run_file
from orchestration.tracking import client as tracking_client
from orchestration.tracking import ensure_experiment, experiment_name, log_batch, tracking_uri

GENERATE_STAGE = "generate"
_MLFLOW_ID = re.compile(r"^[0-9a-f]{32}$")


def resolve_checkpoint(reference: str | Path, dataset: str) -> Path:
    """A ``model.pt`` from a file path, a run directory, ``latest``, a run name or an MLflow run id
    (downloaded from the tracking store when no local run has it)."""
    from orchestration.train import DIFFUSION_STAGE

    if (Path(reference) / MODEL_FILE).is_file():  # a run directory, or a copy of one without run.json
        return Path(reference) / MODEL_FILE
    try:
        return run_file(reference, dataset, DIFFUSION_STAGE, MODEL_FILE, "make train-diffusion")
    except UserError:
        if not _MLFLOW_ID.match(str(reference)):
            raise
    import mlflow

    mlflow.set_tracking_uri(tracking_uri())
    try:
        return Path(mlflow.artifacts.download_artifacts(run_id=str(reference), artifact_path=f"model/{MODEL_FILE}"))
    except Exception as error:  # an unknown id or a run without the file: one line for the user
        raise UserError(f"MLflow run {reference} has no model/{MODEL_FILE} ({type(error).__name__})") from error


class Generator:
    """A loaded checkpoint ready to turn prompts into motions (on a GPU when there is one)."""

    def __init__(self, checkpoint: Checkpoint, source: Path) -> None:
        self.checkpoint = checkpoint
        self.source = source
        self.sampler = TokenSampler(checkpoint.denoiser, checkpoint.text_encoder, checkpoint.schedule)
        self._tagger = None

    @classmethod
    def from_checkpoint(cls, reference: str | Path = "latest", dataset: str = "synthetic",
                        device: str = "auto") -> "Generator":
        path = resolve_checkpoint(reference, dataset)
        if device == "auto":
            device = "cuda" if torch.cuda.is_available() else "cpu"
        try:
            return cls(load_checkpoint(path, device), path)
        except (FileNotFoundError, ValueError, KeyError) as error:
            raise UserError(str(error)) from error

    # ------------------------------------------------------------------------------------ prompts
    @property
    def fps(self) -> float:
        return self.checkpoint.fps

    def seconds_range(self) -> tuple[float, float]:
        """The shortest and longest action this model supports: one token, and the longest clip
        it was trained on."""
        frames = self.checkpoint.frames_per_token
        return frames / self.fps, self.checkpoint.lengths.longest * frames / self.fps

    def _split(self, prompt: str) -> tuple[list[str], list[str | None]]:
        """Action sentences and their verbs, split as the corpus's captions were."""
        from pipelines.language import decompose, load_tagger

        if self._tagger is None:
            data_dir = self.checkpoint.extra.get("data_dir")
            try:
                self._tagger = load_tagger(Path(data_dir) / NLP if data_dir else None)
            except FileNotFoundError as error:
                raise UserError(f"{error} (or pass --no-split)") from error
        parts = decompose(prompt, tagger=self._tagger)
        verbs: list[str | None] = list(parts.verbs) if len(parts.verbs) == len(parts.actions) else [None] * len(parts.actions)
        return list(parts.actions), verbs

    def plan(self, prompts: Sequence[str], seconds: Sequence[float] | None = None,
             split: bool = True) -> tuple[list[str], list[int]]:
        """The action sentences and their lengths in tokens for ``prompts``.

        With ``split`` a prompt with several verbs becomes several actions; a prompt's ``seconds``
        are then shared among its actions in proportion to their typical lengths. Without
        ``seconds`` every action gets the corpus's median length for its verb.
        """
        prompts = [p for p in prompts]
        if not prompts or any(not p.strip() for p in prompts):
            raise UserError("give at least one non-empty prompt")
        if seconds is not None and len(seconds) not in (1, len(prompts)):
            raise UserError(f"give one duration per prompt ({len(prompts)}) or one for all, not {len(seconds)}")
        lo, hi = self.seconds_range()
        per_token = self.checkpoint.frames_per_token / self.fps
        actions: list[str] = []
        lengths: list[int] = []
        for index, prompt in enumerate(prompts):
            if split:
                parts, verbs = self._split(prompt)
            else:
                parts, verbs = [" ".join(prompt.lower().split())], [None]
            typical = [self.checkpoint.lengths.tokens_for(verb) for verb in verbs]
            if seconds is not None:
                wanted = float(seconds[0] if len(seconds) == 1 else seconds[index])
                if not lo <= wanted <= hi * len(parts):
                    raise UserError(f"{wanted:g} s for {prompt!r} is outside what this model supports "
                                    f"({lo:g}–{hi:g} s per action)")
                total = max(len(parts), round(wanted / per_token))
                typical = _share(total, typical)
            actions.extend(parts)
            lengths.extend(typical)
        return actions, lengths

    # --------------------------------------------------------------------------------- generation
    def generate(self, prompts: str | Sequence[str], seconds: float | Sequence[float] | None = None,
                 method: str = "tps", ts: int | None = None, eta: float = 0.25, guidance: float = 2.0, seed: int = 0,
                 truncation: float = 1.0, split: bool = True) -> Motion:
        """One motion doing ``prompts`` in order (paper defaults for several actions: T_s = 90 of
        T = 100 (``None``: 0.9·T), η = 0.25, s = 2)."""
        prompts = [prompts] if isinstance(prompts, str) else list(prompts)
        seconds = [seconds] if isinstance(seconds, (int, float)) else seconds
        actions, lengths = self.plan(prompts, seconds, split)
        options = SamplingOptions(method=method, ts=ts, guidance=guidance, truncation=truncation)
        return self.generate_tokens([actions], [lengths], options, eta=eta, seeds=[seed])[0]

    def generate_tokens(self, actions: list[list[str]], lengths: list[list[int]], options: SamplingOptions,
                        eta: float | None = None, seeds: list[int] | None = None,
                        given: list[torch.Tensor | None] | None = None) -> list[Motion]:
        """Batched generation of ready-made action sentences with lengths in tokens (what
        evaluation uses); ``given`` holds tokens to keep per item (editing)."""
        seeds = list(range(len(actions))) if seeds is None else seeds
        given = [None] * len(actions) if given is None else given
        try:
            requests = [Request([[a] for a in acts], list(lens), seed, kept)
                        for acts, lens, seed, kept in zip(actions, lengths, seeds, given)]
            tokens = self.sampler.sample(requests, options, eta=eta)
        except ValueError as error:
            raise UserError(str(error)) from error
        settings = {**asdict(options), "eta": eta, "checkpoint": str(self.source)}
        return [self.decode(pieces, acts, options, {**settings, "seed": seed})
                for pieces, acts, seed in zip(tokens, actions, seeds)]

    def edit(self, motion: Motion, keep: Sequence[tuple[float, float]], actions: Sequence[str] | None = None,
             method: str = "tps", ts: int | None = None, eta: float = 0.25, guidance: float = 2.0,
             seed: int = 0) -> Motion:
        """Regenerate ``motion`` except the time spans ``keep`` (seconds), whose tokens stay exactly
        as the VQ-VAE encodes them: keep the start and the end to in-between, the start alone to
        complete a prefix. ``actions`` may replace the texts of the motion's actions, one each."""
        actions = list(motion.actions if actions is None else actions)
        if len(actions) != len(motion.actions):
            raise UserError(f"give one text per action of the motion ({len(motion.actions)})")
        per_token = self.checkpoint.frames_per_token
        vq, normalizer = self.checkpoint.vq, self.checkpoint.normalizer
        device = next(vq.parameters()).device
        with torch.no_grad():
            normalized = torch.as_tensor(normalizer.normalize(motion.features), dtype=torch.float32, device=device)
            tokens = vq.encode(normalized[None])[0].cpu()
        bounds = [round(first / per_token) for first, _ in motion.ranges] + [len(tokens)]
        lengths = [b - a for a, b in zip(bounds[:-1], bounds[1:])]
        if min(lengths) < 1:
            raise UserError("every action of the motion must last at least one token to be edited")
        given = torch.full_like(tokens, FREE)
        for start, end in keep:
            first, last = int(start * self.fps / per_token), int(np.ceil(end * self.fps / per_token))
            given[first:last] = tokens[first:last]
        options = SamplingOptions(method=method, ts=ts, guidance=guidance)
        return self.generate_tokens([actions], [lengths], options, eta, [seed], [given])[0]

    def decode(self, pieces: list[torch.Tensor], actions: list[str], options: SamplingOptions,
               settings: dict[str, Any]) -> Motion:
        """Tokens per action → one Motion: decoded together, or (``slerp``) one by one and joined."""
        vq, normalizer, skeleton = self.checkpoint.vq, self.checkpoint.normalizer, self.checkpoint.skeleton
        device = next(vq.parameters()).device
        per_token = self.checkpoint.frames_per_token
        with torch.no_grad():
            decoded = [normalizer.denormalize(vq.decode(p[None].to(device))[0].cpu().numpy())
                       for p in (pieces if options.method == "slerp" else [torch.cat(pieces)])]
        if options.method == "slerp":
            joints, ranges = slerp_join([features_to_joints(f, skeleton) for f in decoded],
                                        options.slerp * per_token, skeleton)
            features = joints_to_features(np.concatenate([joints, joints[-1:]]), skeleton)
        else:
            features = decoded[0]
            joints = features_to_joints(features, skeleton)
            ends = np.cumsum([len(p) * per_token for p in pieces])
            ranges = [(int(end - len(p) * per_token), int(end)) for p, end in zip(pieces, ends)]
        return Motion(features, np.asarray(joints, dtype=np.float32), self.fps, skeleton.name, list(actions),
                      ranges, settings, torch.cat(pieces).cpu().numpy())


def _share(total: int, typical: list[int]) -> list[int]:
    """Split ``total`` tokens among actions in proportion to their typical lengths, at least one each."""
    weights = np.asarray(typical, dtype=np.float64)
    raw = np.maximum(1, np.floor(total * weights / weights.sum())).astype(int)
    raw[np.argmax(weights)] += total - int(raw.sum())
    return [int(n) for n in raw]


def log_generation(motion: Motion, prompts: Sequence[str], files: dict[str, Path], dataset: str) -> str:
    """Record one generation in MLflow (experiment ``<dataset>/generate``): prompts, actions,
    settings as params, the files as artifacts; returns the MLflow run id."""
    experiment_id = ensure_experiment(experiment_name(dataset, GENERATE_STAGE))
    client = tracking_client()
    run = client.create_run(experiment_id, tags={"dataset": dataset, "stage": GENERATE_STAGE,
                                                 "method": str(motion.settings.get("method"))})
    run_id = run.info.run_id
    params = {**{k: str(v) for k, v in motion.settings.items()}, "prompts": " | ".join(prompts)[:500],
              "actions": " | ".join(motion.actions)[:500], "seconds": f"{motion.seconds:.2f}"}
    log_batch(client, run_id, params=params)
    for path in files.values():
        client.log_artifact(run_id, str(path), artifact_path="motion")
    features = files.get("npy")
    if features is not None and features.with_suffix(".json").exists():
        client.log_artifact(run_id, str(features.with_suffix(".json")), artifact_path="motion")
    client.set_terminated(run_id)
    return run_id
