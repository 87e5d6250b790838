"""Self-contained model files, one way for every model: a :class:`ModelFileKind` is a format tag,
the name errors use, and the file's parts registered by name (as diffusers' ``register_modules``
and ``save_pretrained`` do, https://github.com/huggingface/diffusers, ``pipeline_utils.py``).
:meth:`ModelFileKind.save` takes each part by its name and stores it as its :class:`Part` says
(a network as the config it was constructed from and its weights, a text encoder as its kind and
constructor options, a tensor, a normaliser, the length prior, plain values);
:meth:`ModelFileKind.load` gives each part back, restored on a device. Underneath, a file is one
``torch.save`` dict with the tag, written atomically and read back with ``weights_only=True``
(so a file can never run code)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.atomic import atomic_path
from m2d2m.motion.representation.normalization import Normalizer
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


class Part:
    """How one named part of a model file is stored (:meth:`dump`: plain values and tensors) and
    given back (:meth:`load`, on a device). The base class keeps plain values as they are (a config
    section, ``extra``)."""

    def dump(self, value: Any) -> Any:
        return value

    def load(self, stored: Any, device: str | torch.device) -> Any:
        return stored


PLAIN = Part()


class Network(Part):
    """A network (a :class:`~m2d2m.networks.config.NetworkConfig` in ``.config``): stored as that
    config and its weights, rebuilt by ``build(config, weights)`` and loaded in eval mode."""

    def __init__(self, build: Callable[[dict[str, Any], dict[str, Any]], torch.nn.Module]) -> None:
        self.build = build

    @classmethod
    def of(cls, network: type, config: type, *from_weights: str) -> Network:
        """``network(config.from_dict(...), *weights[name] for name in from_weights)``: the
        constructor's config, then any tensors it takes that travel with the weights (a codebook)."""
        return cls(lambda settings, weights: network(config.from_dict(settings), *(weights[k] for k in from_weights)))

    def dump(self, value: torch.nn.Module) -> dict[str, Any]:
        return {"config": value.config.to_dict(), "state_dict": cpu_state(value)}

    def load(self, stored: dict[str, Any], device: str | torch.device) -> torch.nn.Module:
        network = self.build(stored["config"], stored["state_dict"])
        network.load_state_dict(stored["state_dict"])
        return network.to(device).eval()


class Text(Part):
    """A text encoder: its kind and the options it was constructed with, and its weights when it was
    trained (the frozen CLIP tower is found again by its path)."""

    def dump(self, value: TextEncoder) -> dict[str, Any]:
        return {
            "kind": value.kind,
            "options": dict(value.options),
            "state_dict": cpu_state(value) if value.trainable else None,
        }

    def load(self, stored: dict[str, Any], device: str | torch.device) -> TextEncoder:
        if stored["state_dict"] is not None and stored["kind"] == "learned":
            encoder = LearnedTextEncoder.from_state_dict(stored["state_dict"])
        else:
            encoder = build_text_encoder(stored["kind"], **stored["options"])
        return encoder.to(device).eval()


class Float32(Part):
    """A tensor, stored in float32 on the CPU and loaded onto the device."""

    def dump(self, value: torch.Tensor) -> torch.Tensor:
        return value.detach().cpu().to(torch.float32)

    def load(self, stored: torch.Tensor, device: str | torch.device) -> torch.Tensor:
        return stored.to(device)


class Normalization(Part):
    """A :class:`~m2d2m.motion.representation.normalization.Normalizer`: its statistics as float32 tensors."""

    def dump(self, value: Normalizer) -> dict[str, Any]:
        return {
            "mean": torch.as_tensor(np.asarray(value.mean, dtype=np.float32)),
            "std": torch.as_tensor(np.asarray(value.std, dtype=np.float32)),
            "feat_bias": float(value.feat_bias),
        }

    def load(self, stored: dict[str, Any], device: str | torch.device) -> Normalizer:
        return Normalizer(stored["mean"].cpu().numpy(), stored["std"].cpu().numpy(), stored["feat_bias"])


class Lengths(Part):
    """The corpus's :class:`LengthPrior`."""

    def dump(self, value: LengthPrior) -> dict[str, Any]:
        return value.to_payload()

    def load(self, stored: dict[str, Any], device: str | torch.device) -> LengthPrior:
        return LengthPrior(**stored)


@dataclass(frozen=True)
class ModelFileKind:
    """One kind of model file: the format tag its payload carries, how errors name it (with its
    article: ``an M2D2M model file``) and its parts by name. A part named in ``inline`` keeps its
    keys at the top of the payload rather than under its name. A tag changes only when old files
    cannot be read as new ones."""

    format: str
    name: str
    parts: Mapping[str, Part] = field(default_factory=dict)
    inline: frozenset[str] = frozenset()

    def save(self, path: str | Path, **parts: Any) -> Path:
        """Write a file of this kind from its parts, each given by its name (all of them, no others)."""
        if set(parts) != set(self.parts):
            missing, unknown = sorted(set(self.parts) - set(parts)), sorted(set(parts) - set(self.parts))
            raise TypeError(f"{self.name}: parts missing {missing}, unknown {unknown}")
        payload: dict[str, Any] = {}
        for name, part in self.parts.items():
            stored = part.dump(parts[name])
            if name in self.inline:
                payload.update(stored)
            else:
                payload[name] = stored
        return self.write(path, payload)

    def load(self, path: str | Path, device: str | torch.device = "cpu") -> dict[str, Any]:
        """The parts of a file of this kind, restored on ``device`` (networks in eval mode)."""
        return self.restore(self.read(path), device)

    def restore(self, payload: dict[str, Any], device: str | torch.device = "cpu") -> dict[str, Any]:
        """The parts of a payload of this kind (read from its file, or embedded in another)."""
        return {
            name: part.load(payload if name in self.inline else payload[name], device)
            for name, part in self.parts.items()
        }

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
