"""The text–motion evaluator of Guo et al. (Guo et al., CVPR 2022; EricGuo5513/text-to-motion,
``networks/modules.py``), which every text-to-motion
paper's R-precision, matching score, FID, diversity and multimodality are measured with.

A motion (un-normalised features, ``(B, T, D)``) is normalised with the evaluator's *own*
statistics, stripped of its 4 foot-contact dims, turned into one latent per 4 frames by two strided
convolutions (the movement encoder) and summarised by a bidirectional GRU; a caption (HumanML3D
``word/POS`` tokens, wrapped in sos/eos and cropped to 20 words) is turned into word vectors plus
a projected 15-way POS one-hot and summarised by another bidirectional GRU. Both land in one
512-d space where the Euclidean distance is the matching score.

Word vectors are either Guo's GloVe subset (``our_vab``: vectors ``<prefix>_data.npy`` and the
word→row pickle ``<prefix>_idx.pkl``, read from a directory the user gives, never downloaded) or,
when no GloVe files are at hand, an embedding learned with the evaluator over a vocabulary of the
training captions. Either way the table, the vocabulary, the sizes and the statistics travel in one
file (:data:`EVALUATOR_FORMAT`), so the metrics of a run can be reproduced from that file alone.
:func:`load_guo_checkpoint` turns Guo's published ``finest.tar`` into the same module.

Differences from the reference code, on purpose: batches need no sorting (each GRU packs its batch
in an order found on the host and puts its outputs back in the input order), and a clip's
embedding does not depend on how (or how far) its batch is padded.
Guo's convolutions see past a clip's end, so his embeddings do depend on the padding; every clip
here is computed as his loaders present it — normalised, zero-padded to 196 frames — which gives
his numbers exactly, whatever the caller's padding.
"""

from __future__ import annotations

import pickle
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence

from m2d2m.model_files import ModelFileKind, Part, cpu_state
from m2d2m.networks.config import ConfigError, NetworkConfig
from m2d2m.text import UNK, LearnedTextEncoder

CONTACT_DIMS = 4  # the foot contacts, dropped from the motion input
UNIT_LENGTH = 4  # frames per movement latent: two stride-2 convolutions

# Guo's ``POS_enumerator`` order: one-hot positions are part of the published weights.
POS_CATEGORIES = (
    "VERB",
    "NOUN",
    "DET",
    "ADP",
    "NUM",
    "AUX",
    "PRON",
    "ADJ",
    "ADV",
    "Loc_VIP",
    "Body_VIP",
    "Obj_VIP",
    "Act_VIP",
    "Desc_VIP",
    "OTHER",
)
POS_INDEX = {name: i for i, name in enumerate(POS_CATEGORIES)}
OTHER = POS_INDEX["OTHER"]

# Words whose category replaces their spaCy tag (Guo's ``utils/word_vectorizer.py`` lists).
_VIP_WORDS: dict[str, frozenset[str]] = {
    "Loc_VIP": frozenset(
        {
            "left",
            "right",
            "clockwise",
            "counterclockwise",
            "anticlockwise",
            "forward",
            "back",
            "backward",
            "up",
            "down",
            "straight",
            "curve",
        }
    ),
    "Body_VIP": frozenset(
        {"arm", "chin", "foot", "feet", "face", "hand", "mouth", "leg", "waist", "eye", "knee", "shoulder", "thigh"}
    ),
    "Obj_VIP": frozenset(
        {"stair", "dumbbell", "chair", "window", "floor", "car", "ball", "handrail", "baseball", "basketball"}
    ),
    "Act_VIP": frozenset(
        {
            "walk",
            "run",
            "swing",
            "pick",
            "bring",
            "kick",
            "put",
            "squat",
            "throw",
            "hop",
            "dance",
            "jump",
            "turn",
            "stumble",
            "stop",
            "sit",
            "lift",
            "lower",
            "raise",
            "wash",
            "stand",
            "kneel",
            "stroll",
            "rub",
            "bend",
            "balance",
            "flap",
            "jog",
            "shuffle",
            "lean",
            "rotate",
            "spin",
            "spread",
            "climb",
        }
    ),
    "Desc_VIP": frozenset(
        {
            "slowly",
            "carefully",
            "fast",
            "careful",
            "slow",
            "quickly",
            "happy",
            "angry",
            "sad",
            "happily",
            "angrily",
            "sadly",
        }
    ),
}
VIP_CATEGORY = {word: POS_INDEX[category] for category, words in _VIP_WORDS.items() for word in words}

# The unknown / start / end words of each kind of word table: Guo's GloVe subset has them as plain
# words; a learned vocabulary uses bracketed ones that no corpus word can collide with.
SPECIAL_WORDS = {
    "glove": {"unk": "unk", "sos": "sos", "eos": "eos"},
    "learned": {"unk": UNK, "sos": "<sos>", "eos": "<eos>"},
}


@dataclass(frozen=True)
class EvaluatorConfig(NetworkConfig):
    """Sizes of the evaluator; the defaults are Guo's HumanML3D ones, so ``finest.tar`` fits them
    (KIT-ML: ``feature_dim=251``). A demo shrinks the widths, never the structure."""

    feature_dim: int = 263
    movement_hidden: int = 512
    movement_latent: int = 512
    motion_hidden: int = 1024
    text_hidden: int = 512
    embedding_dim: int = 512
    word_dim: int = 300
    word_features: str = "glove"  # or "learned": see TextMotionEvaluator
    max_text_len: int = 20  # words kept of a caption, before sos/eos
    max_motion_length: int = 196  # frames every clip is zero-padded to, as the weights saw it
    dropout: float = 0.2

    def __post_init__(self) -> None:
        self.require_positive(
            "movement_hidden",
            "movement_latent",
            "motion_hidden",
            "text_hidden",
            "embedding_dim",
            "word_dim",
            "max_text_len",
            "max_motion_length",
        )
        if not isinstance(self.feature_dim, int) or self.feature_dim <= CONTACT_DIMS:
            raise ConfigError(
                f"EvaluatorConfig.feature_dim must be an integer above {CONTACT_DIMS}, got {self.feature_dim!r}"
            )
        self.require_choice("word_features", sorted(SPECIAL_WORDS))
        self.require_fraction("dropout")


# --------------------------------------------------------------------------------------------------
# Words


def split_token(token: str) -> tuple[str, str]:
    """``"walk/VERB"`` → ``("walk", "VERB")``, the word lower-cased (HumanML3D's token format)."""
    word, slash, pos = token.rpartition("/")
    if not slash or not word:
        raise ValueError(f"malformed caption token {token!r}: expected word/POS, as in the shards' meta.json")
    return word.lower(), pos


def learned_vocabulary(captions: Iterable[Sequence[str]], min_count: int = 1) -> list[str]:
    """The word list of a learned word table: the text encoder's vocabulary of the captions' words
    (``<pad>``, ``<unk>``, words seen ``min_count`` times, most frequent first), then sos and eos."""
    sentences = (" ".join(split_token(token)[0] for token in tokens) for tokens in captions)
    specials = SPECIAL_WORDS["learned"]
    return [*LearnedTextEncoder.build_vocabulary(sentences, min_count), specials["sos"], specials["eos"]]


class _WordIndexUnpickler(pickle.Unpickler):
    """Reads a word → row pickle and nothing else: plain dicts, strings and integers need no
    class, NumPy integers need only NumPy's scalar and dtype; any other class a file names is
    refused, so a tampered file cannot run code."""

    _ALLOWED = {("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"), ("numpy", "dtype")}

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"a word index holds words and rows only, not {module}.{name}")
        return super().find_class(module, name)


def _read_word_index(path: Path) -> dict[str, int]:
    try:
        with open(path, "rb") as handle:
            index = _WordIndexUnpickler(handle).load()
    except (pickle.UnpicklingError, EOFError, ValueError) as error:
        raise ValueError(f"{path} is not a word index ({error})") from error
    if not isinstance(index, dict) or not all(isinstance(w, str) and int(r) == r for w, r in index.items()):
        raise ValueError(f"{path} is not a word index (a dict of word → row)")
    return index


def load_glove(glove_dir: str | Path, prefix: str = "our_vab") -> tuple[list[str], torch.Tensor]:
    """Guo's GloVe subset from ``glove_dir``: ``<prefix>_data.npy`` (V, 300) and ``<prefix>_idx.pkl``
    (word → row, read by a restricted unpickler). Returns the words in row order and the vectors."""
    glove_dir = Path(glove_dir)
    vectors_path, index_path = glove_dir / f"{prefix}_data.npy", glove_dir / f"{prefix}_idx.pkl"
    for path in (vectors_path, index_path):
        if not path.is_file():
            raise FileNotFoundError(
                f"{path}: missing; GloVe files come from text-to-motion's glove/ directory "
                "(glove.zip), and are never downloaded here"
            )
    vectors = np.load(vectors_path, allow_pickle=False)
    index = _read_word_index(index_path)
    rows = sorted(int(row) for row in index.values())
    if vectors.ndim != 2 or rows != list(range(len(vectors))):
        raise ValueError(
            f"{index_path} and {vectors_path} disagree: {len(index)} words with rows "
            f"{rows[:1]}…{rows[-1:]} for vectors of shape {vectors.shape}"
        )
    words = [""] * len(vectors)
    for word, row in index.items():
        words[int(row)] = str(word)
    return words, torch.as_tensor(vectors, dtype=torch.float32)


# --------------------------------------------------------------------------------------------------
# Networks


def _xavier(module: nn.Module) -> None:
    """Guo's initialisation of every convolution and linear layer: Xavier-normal weights, zero bias."""
    if isinstance(module, (nn.Conv1d, nn.Linear)):
        nn.init.xavier_normal_(module.weight)
        nn.init.zeros_(module.bias)


class MovementEncoder(nn.Module):
    """Guo's ``MovementConvEncoder``: two stride-2 convolutions (one latent per 4 frames) and a
    per-latent linear layer. (B, T, C) → (B, T // 4, latent)."""

    def __init__(self, input_dim: int, hidden: int, latent: int, dropout: float) -> None:
        super().__init__()
        self.convs = nn.Sequential(
            nn.Conv1d(input_dim, hidden, 4, 2, 1),
            nn.Dropout(dropout),
            nn.LeakyReLU(0.2),
            nn.Conv1d(hidden, latent, 4, 2, 1),
            nn.Dropout(dropout),
            nn.LeakyReLU(0.2),
        )
        self.project = nn.Linear(latent, latent)
        self.apply(_xavier)

    def forward(self, x: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """Each row computed as if it were ``frames`` long (≤ T, zero beyond its content): the
        first convolution's outputs past ``frames // 2`` are zeroed, as the second convolution's
        own padding would be for a tensor of that length."""
        hidden = self.convs[:3](x.transpose(1, 2))
        inside = torch.arange(hidden.shape[-1], device=x.device) < (frames // 2)[:, None]
        hidden = hidden * inside[:, None, :].to(hidden.dtype)
        return self.project(self.convs[3:](hidden).transpose(1, 2))


class BiGRUEncoder(nn.Module):
    """Guo's ``*EncoderBiGRUCo``: linear input projection, a bidirectional GRU from a learned
    initial state over the packed sequence, and a head on its two final states."""

    def __init__(self, input_dim: int, hidden: int, output_dim: int) -> None:
        super().__init__()
        self.input_projection = nn.Linear(input_dim, hidden)
        self.gru = nn.GRU(hidden, hidden, batch_first=True, bidirectional=True)
        self.head = nn.Sequential(
            nn.Linear(2 * hidden, hidden), nn.LayerNorm(hidden), nn.LeakyReLU(0.2), nn.Linear(hidden, output_dim)
        )
        self.initial_hidden = nn.Parameter(torch.randn(2, 1, hidden))
        self.input_projection.apply(_xavier)
        self.head.apply(_xavier)

    def forward(self, x: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        """(B, L, input_dim) and (B,) lengths ≥ 1 → (B, output_dim), in input order.

        ``lengths`` are best on the host, where packing reads them (``PackedSequence`` keeps its
        batch sizes there): from a GPU they would be copied back first, which waits for it. The
        packing order is found on the host too, and its indices reach the device without waiting
        (``pack_padded_sequence`` would copy its own order there with a blocking copy)."""
        h = self.input_projection(x)
        lengths = lengths.cpu()
        order = torch.argsort(lengths, descending=True, stable=True)
        ordered = h.index_select(0, order.to(h.device, non_blocking=True))
        initial = self.initial_hidden.expand(-1, x.shape[0], -1).contiguous()  # one state for every row
        _, last = self.gru(pack_padded_sequence(ordered, lengths[order], batch_first=True), initial)
        last = last.index_select(1, torch.argsort(order).to(h.device, non_blocking=True))
        return self.head(torch.cat([last[0], last[1]], dim=-1))


class CaptionEncoder(BiGRUEncoder):
    """Guo's ``TextEncoderBiGRUCo``: the POS one-hot, projected to the word size, is added to the
    word vector before the BiGRU encoder."""

    def __init__(self, word_dim: int, hidden: int, output_dim: int) -> None:
        super().__init__(word_dim, hidden, output_dim)
        self.pos_projection = nn.Linear(len(POS_CATEGORIES), word_dim)
        self.pos_projection.apply(_xavier)

    def forward(self, words: torch.Tensor, pos: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        return super().forward(words + self.pos_projection(pos), lengths)


class TextMotionEvaluator(nn.Module):
    """Text and motion co-embedding. ``vocabulary`` lists the word table's rows (from
    :func:`learned_vocabulary`, or :func:`load_glove` together with its ``word_vectors``, which
    stay frozen). The normalisation statistics are buffers: set them with :meth:`set_statistics`."""

    def __init__(
        self, config: EvaluatorConfig, vocabulary: Sequence[str], word_vectors: torch.Tensor | None = None
    ) -> None:
        super().__init__()
        self.config = config
        self.vocabulary = list(vocabulary)
        self.word_index = {word: row for row, word in enumerate(self.vocabulary)}
        self.special = {name: self._row(word) for name, word in SPECIAL_WORDS[config.word_features].items()}
        self.words = nn.Embedding(len(self.vocabulary), config.word_dim)
        if config.word_features == "glove":
            if word_vectors is None or tuple(word_vectors.shape) != (len(self.vocabulary), config.word_dim):
                found = None if word_vectors is None else tuple(word_vectors.shape)
                raise ValueError(
                    f"GloVe word features need word_vectors of shape ({len(self.vocabulary)}, "
                    f"{config.word_dim}), got {found}"
                )
            self.words.weight.data.copy_(word_vectors)
            self.words.weight.requires_grad_(False)
        elif word_vectors is not None:
            raise ValueError("learned word features are trained: pass no word_vectors")
        self.movement = MovementEncoder(
            config.feature_dim - CONTACT_DIMS, config.movement_hidden, config.movement_latent, config.dropout
        )
        self.motion = BiGRUEncoder(config.movement_latent, config.motion_hidden, config.embedding_dim)
        self.text = CaptionEncoder(config.word_dim, config.text_hidden, config.embedding_dim)
        self.register_buffer("feature_mean", torch.zeros(config.feature_dim))
        self.register_buffer("feature_scale", torch.ones(config.feature_dim))

    def _row(self, word: str) -> int:
        if word not in self.word_index:
            raise ValueError(
                f"the vocabulary lacks the word {word!r}, which {self.config.word_features} word "
                "features need (build it with learned_vocabulary or load_glove)"
            )
        return self.word_index[word]

    @property
    def device(self) -> torch.device:
        return self.feature_mean.device

    def set_statistics(self, mean: np.ndarray | torch.Tensor, scale: np.ndarray | torch.Tensor) -> None:
        """The evaluator's own normalisation ``(x − mean) / scale`` (scale: the std as trained with,
        feat_bias already applied)."""
        for buffer, values in ((self.feature_mean, mean), (self.feature_scale, scale)):
            values = torch.as_tensor(values, dtype=torch.float32)
            if values.shape != buffer.shape:
                raise ValueError(f"statistics of shape {tuple(values.shape)} for {self.config.feature_dim}-d features")
            buffer.copy_(values)

    def tokenize(self, captions: Sequence[Sequence[str]]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Captions as lists of ``word/POS`` tokens → word rows (B, L) and POS categories (B, L) on
        the evaluator's device, laid out on the host and copied without waiting for the device, and
        lengths (B,) on the CPU. Each caption is cropped to ``max_text_len`` words
        and wrapped in sos/eos (tagged OTHER); an unknown word becomes unk, tagged OTHER; a known
        word of Guo's VIP lists takes its VIP category instead of its tag."""
        rows: list[list[int]] = []
        categories: list[list[int]] = []
        for tokens in captions:
            row, category = [self.special["sos"]], [OTHER]
            for word, pos in map(split_token, list(tokens)[: self.config.max_text_len]):
                if word in self.word_index:
                    row.append(self.word_index[word])
                    category.append(VIP_CATEGORY.get(word, POS_INDEX.get(pos, OTHER)))
                else:
                    row.append(self.special["unk"])
                    category.append(OTHER)
            rows.append(row + [self.special["eos"]])
            categories.append(category + [OTHER])
        longest = max(len(row) for row in rows)
        words = torch.tensor([row + [self.special["unk"]] * (longest - len(row)) for row in rows])
        pos = torch.tensor([category + [OTHER] * (longest - len(category)) for category in categories])
        lengths = torch.tensor([len(row) for row in rows])
        return words.to(self.device, non_blocking=True), pos.to(self.device, non_blocking=True), lengths

    def embed_text(self, captions: Sequence[Sequence[str]]) -> torch.Tensor:
        """Captions (lists of ``word/POS`` tokens) → (B, embedding_dim)."""
        if not captions:
            raise ValueError("embed_text needs at least one caption")
        words, pos, lengths = self.tokenize(captions)
        # a comparison, not F.one_hot, which checks its input's range on the host
        one_hot = (pos[..., None] == torch.arange(len(POS_CATEGORIES), device=pos.device)).to(self.words.weight.dtype)
        return self.text(self.words(words), one_hot, lengths)

    def embed_motion(self, features: torch.Tensor, lengths: torch.Tensor | Sequence[int]) -> torch.Tensor:
        """Un-normalised features (B, T, feature_dim), padded with anything or not at all, and
        lengths (B,) in frames → (B, embedding_dim). Each clip is encoded as Guo's loaders present
        it: normalised, zero-padded to ``max_motion_length`` frames (a longer clip: not padded).
        The GRU reads ``length // 4`` latents, so lengths are best multiples of 4, as Guo crops them.
        The lengths are best given on the host, where they are checked and packed by
        (:class:`BiGRUEncoder`), and copied to the device without waiting for it."""
        if features.ndim != 3 or features.shape[-1] != self.config.feature_dim:
            raise ValueError(f"expected features (B, T, {self.config.feature_dim}), got {tuple(features.shape)}")
        host = torch.as_tensor(lengths).cpu()
        if host.shape != features.shape[:1] or not bool(((host >= UNIT_LENGTH) & (host <= features.shape[1])).all()):
            raise ValueError(
                f"lengths must be one per clip, from {UNIT_LENGTH} to {features.shape[1]} frames, got {host.tolist()}"
            )
        lengths = host.to(features.device, non_blocking=True)
        frames = lengths.clamp(min=self.config.max_motion_length)
        x = (features - self.feature_mean) / self.feature_scale
        # as far as the longest of `frames`: max_motion_length, since no length exceeds the clips'
        x = F.pad(x, (0, 0, 0, max(0, self.config.max_motion_length - x.shape[1])))
        valid = torch.arange(x.shape[1], device=x.device) < lengths[:, None]
        x = torch.where(valid[..., None], x, torch.zeros((), dtype=x.dtype, device=x.device))
        latents = self.movement(x[..., :-CONTACT_DIMS], frames)
        return self.motion(latents, host // UNIT_LENGTH)


class ContrastiveTerms(NamedTuple):
    """The contrastive loss and its two parts."""

    total: torch.Tensor
    positive: torch.Tensor
    negative: torch.Tensor


def contrastive_loss(
    text: torch.Tensor, motion: torch.Tensor, shift: int | torch.Tensor, margin: float = 10.0
) -> ContrastiveTerms:
    """Guo's (Hadsell's) contrastive loss: matched pairs pull together (d²), and each caption is
    pushed at least ``margin`` away from the motion ``shift`` rows further on in the batch
    (max(0, margin − d)²); each part is a batch mean. ``shift`` lies in [1, B − 1], so every
    negative is another clip (Guo's draw could also pick shift 0, a positive scored as a negative);
    a number is checked, a tensor (drawn on the device by a training step) is trusted, as reading it
    would make the host wait."""
    if not isinstance(shift, torch.Tensor) and not 1 <= shift < len(text):
        raise ValueError(f"shift must lie in [1, {len(text) - 1}] for a batch of {len(text)}, got {shift}")
    rows = torch.arange(len(motion), device=motion.device)
    positive = F.pairwise_distance(text, motion).pow(2).mean()
    negative = (margin - F.pairwise_distance(text, motion[(rows + shift) % len(motion)])).clamp(min=0).pow(2).mean()
    return ContrastiveTerms(positive + negative, positive, negative)


# --------------------------------------------------------------------------------------------------
# Files


class _EvaluatorNetwork(Part):
    """The evaluator in its file: sizes, vocabulary, and every weight, word vector and statistic."""

    def dump(self, value: TextMotionEvaluator) -> dict[str, Any]:
        return {"config": value.config.to_dict(), "vocabulary": list(value.vocabulary), "state_dict": cpu_state(value)}

    def load(self, stored: dict[str, Any], device: str | torch.device) -> TextMotionEvaluator:
        config = EvaluatorConfig.from_dict(stored["config"])
        state = stored["state_dict"]
        model = TextMotionEvaluator(
            config, stored["vocabulary"], state["words.weight"] if config.word_features == "glove" else None
        )
        model.load_state_dict(state)
        return model.to(device).eval()


# one self-contained file, all that computing the metrics needs: ``EVALUATOR_FORMAT.save(path, model=...)``
EVALUATOR_FORMAT = ModelFileKind(
    "m2d2m-evaluator/1", "an evaluator model file", {"model": _EvaluatorNetwork()}, inline=frozenset({"model"})
)


def load_evaluator(path: str | Path, map_location: str | torch.device = "cpu") -> TextMotionEvaluator:
    """The evaluator of an evaluator model file, in eval mode on ``map_location``."""
    return EVALUATOR_FORMAT.load(path, map_location)["model"]


# Guo's module and layer names (``finest.tar`` keys, ``networks/modules.py`` attributes) → ours.
GUO_MODULES = {"movement_encoder": "movement", "text_encoder": "text", "motion_encoder": "motion"}
GUO_LAYERS = {
    "main": "convs",
    "out_net": "project",
    "input_emb": "input_projection",
    "pos_emb": "pos_projection",
    "gru": "gru",
    "output_net": "head",
    "hidden": "initial_hidden",
}


def _guo_checkpoint_file(checkpoint_dir: Path) -> Path:
    """``finest.tar`` given itself, its ``model/`` directory, or the ``text_mot_match`` run above."""
    for candidate in (checkpoint_dir, checkpoint_dir / "finest.tar", checkpoint_dir / "model" / "finest.tar"):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(
        f"{checkpoint_dir}: no finest.tar there, nor in its model/ (Guo's evaluator is "
        "checkpoints/t2m/text_mot_match/model/finest.tar of text-to-motion's download)"
    )


_OUR_MODULES = {ours: guo for guo, ours in GUO_MODULES.items()}
_OUR_LAYERS = {ours: guo for guo, ours in GUO_LAYERS.items()}


def _guo_name(key: str) -> str:
    """One of our weight names as Guo's checkpoint would name it, for error messages."""
    module, _, rest = key.partition(".")
    layer, dot, rest = rest.partition(".")
    return f"{_OUR_MODULES[module]}.{_OUR_LAYERS[layer]}{dot}{rest}"


def _guo_state(checkpoint: dict[str, Any], path: Path) -> dict[str, torch.Tensor]:
    """Guo's three module state dicts, renamed to this module's keys."""
    missing = [name for name in GUO_MODULES if name not in checkpoint]
    if missing:
        raise ValueError(
            f"{path}: not Guo's text-motion evaluator, it lacks {', '.join(missing)} "
            f"(found keys: {', '.join(map(str, checkpoint))})"
        )
    state = {}
    for module, ours in GUO_MODULES.items():
        for key, value in checkpoint[module].items():
            layer, dot, rest = key.partition(".")
            if layer not in GUO_LAYERS:
                raise ValueError(f"{path}: unexpected weight {module}.{key} for Guo's evaluator")
            state[f"{ours}.{GUO_LAYERS[layer]}{dot}{rest}"] = value
    return state


def _require_shapes(model: TextMotionEvaluator, state: dict[str, torch.Tensor], path: Path) -> None:
    """Name every missing, unexpected or differently shaped weight, in Guo's terms, before loading any."""
    expected = {
        key: tuple(value.shape) for key, value in model.state_dict().items() if key.split(".")[0] in _OUR_MODULES
    }
    problems = [f"{_guo_name(key)} missing" for key in expected if key not in state]
    problems += [f"{_guo_name(key)} unexpected" for key in state if key not in expected]
    problems += [
        f"{_guo_name(key)} has shape {tuple(value.shape)}, expected {expected[key]}"
        for key, value in state.items()
        if key in expected and tuple(value.shape) != expected[key]
    ]
    if problems:
        raise ValueError(
            f"{path} does not fit Guo's evaluator for {model.config.feature_dim}-d features (from the "
            f"meta statistics) and {model.config.word_dim}-d word vectors: " + "; ".join(problems)
        )


def load_guo_checkpoint(
    checkpoint_dir: str | Path,
    glove_dir: str | Path,
    meta_dir: str | Path,
    glove_prefix: str = "our_vab",
    map_location: str | torch.device = "cpu",
) -> TextMotionEvaluator:
    """Guo's published evaluator as a :class:`TextMotionEvaluator` (eval mode): the weights of
    ``finest.tar`` (its ``movement_encoder``, ``text_encoder`` and ``motion_encoder`` state dicts,
    whose layer names are assumed to be the attribute names of Guo's modules, ``GUO_LAYERS``),
    GloVe from ``glove_dir``, and the evaluator's *own* statistics ``mean.npy`` / ``std.npy``
    from ``meta_dir`` (the run's ``meta/``; MDM's ``t2m_mean.npy`` / ``t2m_std.npy`` are copies),
    used as they are: their std already carries the training-time feat_bias division."""
    path = _guo_checkpoint_file(Path(checkpoint_dir))
    meta_dir = Path(meta_dir)
    stats = []
    for name in ("mean.npy", "std.npy"):
        if not (meta_dir / name).is_file():
            raise FileNotFoundError(
                f"{meta_dir / name}: missing; the evaluator's statistics are the meta/mean.npy "
                "and meta/std.npy of its run (MDM's dataset/t2m_mean.npy, t2m_std.npy)"
            )
        stats.append(np.load(meta_dir / name, allow_pickle=False).astype(np.float32))
    mean, std = stats
    if mean.ndim != 1 or mean.shape != std.shape:
        raise ValueError(f"{meta_dir}: mean.npy {mean.shape} and std.npy {std.shape} must be equal 1-d arrays")
    vocabulary, vectors = load_glove(glove_dir, glove_prefix)
    config = EvaluatorConfig(feature_dim=len(mean), word_dim=vectors.shape[1], word_features="glove")
    model = TextMotionEvaluator(config, vocabulary, vectors)
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # a corrupt or foreign file: say which
        raise ValueError(f"{path} is not a readable torch checkpoint ({type(error).__name__}: {error})") from error
    if not isinstance(checkpoint, dict):
        raise ValueError(f"{path}: not Guo's text-motion evaluator (a {type(checkpoint).__name__}, not a dict)")
    state = _guo_state(checkpoint, path)
    _require_shapes(model, state, path)
    model.load_state_dict({**model.state_dict(), **state})
    model.set_statistics(mean, std)
    return model.to(map_location).eval()
