"""The M2D2M checkpoint keeps the whole transition schedule it was trained with (a configured ᾱ_T or
γ̄_T comes back from the file, not the named schedule's default) and the sampling defaults its
config chose."""

from dataclasses import replace

import pytest

from m2d2m.generators.m2d2m.checkpoint import M2D2M_FORMAT, load_m2d2m, sampling_defaults
from m2d2m.generators.m2d2m.generator import M2D2MGenerator
from m2d2m.generators.m2d2m.options import MULTI_ACTION, SINGLE_ACTION
from m2d2m.generators.options import MULTI, SINGLE
from m2d2m.model_files import LengthPrior
from m2d2m.text import LearnedTextEncoder
from tests.helpers import TINY_DIFFUSION, random_vq
from training.m2d2m_module import M2D2MModule


def test_configured_schedule_endpoints_survive_the_round_trip(tiny_data, tmp_path):
    vq, _ = random_vq(tmp_path / "vq.pt", tiny_data, seed=0)
    diffusion = {**TINY_DIFFUSION["diffusion"], "alpha_bar_end": 0.2, "gamma_bar_end": 0.5}
    module = M2D2MModule(
        TINY_DIFFUSION["denoiser"],
        TINY_DIFFUSION["text"],
        diffusion,
        TINY_DIFFUSION["optim"],
        codebook=vq.codebook,
        vocabulary=LearnedTextEncoder.build_vocabulary(["a person walks"]),
    )
    assert (module.schedule.config.alpha_bar_end, module.schedule.config.gamma_bar_end) == (0.2, 0.5)
    path = M2D2M_FORMAT.save(
        tmp_path / "model.pt",
        **module.model_parts(),
        vq=tmp_path / "vq.pt",
        lengths=LengthPrior({}, 5, 10),
        extra={},
        sampling={},
    )
    loaded = load_m2d2m(path)
    assert loaded.schedule.config == module.schedule.config
    assert loaded.schedule.gamma_bar[-1].item() == 0.5  # the matrices are rebuilt from it, not from "linear"


def test_the_model_files_sampling_defaults_reach_every_preset(tiny_data, tmp_path):
    """A config's ``sampling`` section travels in the file and is where every preset starts from;
    what it does not name stays the paper's preset, and a knob it may not set is refused."""
    vq, _ = random_vq(tmp_path / "vq.pt", tiny_data, seed=0)
    module = M2D2MModule(
        TINY_DIFFUSION["denoiser"],
        TINY_DIFFUSION["text"],
        TINY_DIFFUSION["diffusion"],
        TINY_DIFFUSION["optim"],
        codebook=vq.codebook,
        vocabulary=LearnedTextEncoder.build_vocabulary(["a person walks"]),
    )

    def save(sampling):
        return M2D2M_FORMAT.save(
            tmp_path / "model.pt",
            **module.model_parts(),
            vq=tmp_path / "vq.pt",
            lengths=LengthPrior({}, 5, 10),
            extra={},
            sampling=sampling_defaults(sampling, module.schedule.config.steps),
        )

    generator = M2D2MGenerator.load(save({"steps": 3, "guidance": 1.0}))
    for preset, paper in ((MULTI, MULTI_ACTION), (SINGLE, SINGLE_ACTION)):
        assert generator.preset(preset) == replace(paper, steps=3, guidance=1.0)
    assert M2D2MGenerator.load(save({})).preset(SINGLE) == SINGLE_ACTION
    with pytest.raises(ValueError, match="sampling.eta: a model's sampling defaults are steps, truncation, guidance"):
        save({"eta": 0.3})
    with pytest.raises(ValueError, match=r"option guidance must be \[0, 20\]"):
        save({"guidance": -1.0})
