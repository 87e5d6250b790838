"""Self-contained model files: one ``torch.save`` dict with a format tag, written atomically and
read back with ``weights_only=True`` (so a file can never run code), shared by every model
(:class:`ModelFileKind`: a kind of file is its tag and its name in errors); and the parts every
generator's file holds beside its network: the network's config and weights, the text encoder,
the corpus's length prior and free-form ``extra``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.atomic import atomic_path
from m2d2m.text import LearnedTextEncoder, TextEncoder, build_text_encoder


def check_plain(value: Any, where: str = "extra") -> None:
    """Reject what ``torch.load(weights_only=True)`` could not read back, at save time."""
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, (str, int)):
                raise TypeError(f"{where}: keys must be str or int, got {type(key).__name__}")
            check_plain(item, f"{where}[{key!r}]")
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            check_plain(item, f"{where}[{i}]")
    # Exact types: NumPy scalars subclass float but are not loadable with weights_only.
    elif not (value is None or type(value) in (str, int, float, bool) or isinstance(value, torch.Tensor)):
        raise TypeError(
            f"{where}: {type(value).__name__} cannot be stored in a model file (use plain Python values or tensors)"
        )


def cpu_state(module: torch.nn.Module) -> dict[str, Any]:
    """A module's state dict detached on the CPU; non-tensor extra state (a vocabulary) as it is."""
    return {k: v.detach().cpu() if isinstance(v, torch.Tensor) else v for k, v in module.state_dict().items()}


@dataclass(frozen=True)
class ModelFileKind:
    """One kind of model file: the format tag its payload carries and how errors name it (with its
    article: ``an M2D2M model file``). A tag changes only when old files cannot be read as new ones."""

    format: str
    name: str

    def write(self, path: str | Path, payload: dict[str, Any]) -> Path:
        """Save ``payload`` tagged as this kind through a temporary file, so readers never see half a file."""
        payload = {"format": self.format, **payload}
        check_plain(payload, "payload")
        path = Path(path)
        with atomic_path(path) as partial:
            torch.save(payload, partial)
        return path

    def read(self, path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
        """The payload of a file of this kind; FileNotFoundError, or ValueError naming the kind expected."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no {self.name.split(' ', 1)[1]} at {path}")
        try:
            payload = torch.load(path, map_location=map_location, weights_only=True)
        except Exception as error:  # any unreadable file is, for the caller, simply not this kind of file
            # torch's own text runs to paragraphs (and advises weights_only=False): its first sentence
            first = str(error).strip().split(". ", 1)[0].splitlines()[0].rstrip(".") if str(error).strip() else ""
            raise ValueError(
                f"{path} is not {self.name}: truncated, damaged or not written by torch.save "
                f"({type(error).__name__}: {first})"
            ) from error
        found = payload.get("format") if isinstance(payload, dict) else None
        if found != self.format:
            raise ValueError(f"{path} is not {self.name} (format {found!r}, expected {self.format!r})")
        return payload


def network_payload(network: torch.nn.Module) -> dict[str, Any]:
    """A network in a model file: its config (a :class:`~m2d2m.networks.config.NetworkConfig`) and weights."""
    return {"config": network.config.to_dict(), "state_dict": cpu_state(network)}


@dataclass
class LengthPrior:
    """Typical lengths in a model's steps (tokens; frames for a model on features): the median
    per verb over single-action training captions, and the median over all of them for verbs
    never seen alone; ``longest`` is the longest clip."""

    per_verb: dict[str, int]
    median: int
    longest: int

    def typical(self, verb: str | None) -> int:
        """The typical length of an action with this verb, in the model's steps (the median without one)."""
        return self.per_verb.get(verb or "", self.median)

    def to_payload(self) -> dict[str, Any]:
        return {"per_verb": dict(self.per_verb), "median": int(self.median), "longest": int(self.longest)}


def text_payload(encoder: TextEncoder, text: dict[str, Any]) -> dict[str, Any]:
    """A text encoder in a model file: its kind and options (the run's ``text`` section), and its
    weights when it was trained (the frozen CLIP tower is found again by its path)."""
    return {
        "kind": text.get("kind", "learned"),
        "options": {k: v for k, v in text.items() if k != "kind"},
        "state_dict": cpu_state(encoder) if encoder.trainable else None,
    }


def text_encoder_from_payload(payload: dict[str, Any]) -> TextEncoder:
    if payload["state_dict"] is not None and payload["kind"] == "learned":
        return LearnedTextEncoder.from_state_dict(payload["state_dict"])
    return build_text_encoder(payload["kind"], **payload["options"])
