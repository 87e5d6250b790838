"""The M2D2M checkpoint keeps the whole transition schedule it was trained with: a configured
ᾱ_T or γ̄_T comes back from the file, not the named schedule's default."""

from m2d2m.generators.m2d2m_checkpoint import load_checkpoint, save_checkpoint
from m2d2m.model_files import LengthPrior
from m2d2m.text import LearnedTextEncoder
from tests.helpers import TINY_DIFFUSION, random_vq
from training.m2d2m_module import M2D2MModule


def test_configured_schedule_endpoints_survive_the_round_trip(tiny_data, tmp_path):
    vq, _ = random_vq(tmp_path / "vq.pt", tiny_data, seed=0)
    diffusion = {**TINY_DIFFUSION["diffusion"], "alpha_bar_end": 0.2, "gamma_bar_end": 0.5}
    module = M2D2MModule(TINY_DIFFUSION["denoiser"], TINY_DIFFUSION["text"], diffusion, TINY_DIFFUSION["optim"],
                         codebook=vq.codebook, vocabulary=LearnedTextEncoder.build_vocabulary(["a person walks"]))
    assert (module.schedule.config.alpha_bar_end, module.schedule.config.gamma_bar_end) == (0.2, 0.5)
    path = save_checkpoint(tmp_path / "model.pt", module.denoiser, module.text_encoder, TINY_DIFFUSION["text"],
                           module.schedule.config, module.codebook, tmp_path / "vq.pt", LengthPrior({}, 5, 10))
    loaded = load_checkpoint(path)
    assert loaded.schedule.config == module.schedule.config
    assert loaded.schedule.gamma_bar[-1].item() == 0.5  # the matrices are rebuilt from it, not from "linear"
