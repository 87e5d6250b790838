"""Text to motion for people: `m2d2m generate` with any registered model.

One module per job, in the order a generation goes through them:

- :mod:`~orchestration.generate.outputs`: where the files go and in which formats, checked before
  anything is loaded (:func:`plan_output`), and written all or nothing (:func:`staged`);
- :mod:`~orchestration.generate.prompts`: what is asked, checked and planned: prompts split into
  action sentences with the dataset's tagger, each action's length, the cap on the whole;
- :mod:`~orchestration.generate.loading`: the model file found and its generator loaded;
- :mod:`~orchestration.generate.sampling`: the generator sampled (a new motion, an edit, body-part
  control) and the joints put on one rigid skeleton;
- :mod:`~orchestration.generate.saving`: the files written into a run folder whose ``run.json``
  says how it ended, and the generation recorded in MLflow.

The names below are the package's API, as the web app and docs/generation.md use it.
"""

from orchestration.generate.loading import load_generator, resolve_model_file
from orchestration.generate.outputs import Output, check_free, plan_output, staged, variations
from orchestration.generate.prompts import (
    DEFAULT_MAX_SECONDS,
    PromptPlanner,
    action_frames,
    check_length,
    check_prompted,
    check_seconds,
    length_cap,
    plan_parts,
    require_words,
    seconds_range,
)
from orchestration.generate.sampling import edit, edit_part, generate, generate_parts
from orchestration.generate.saving import GENERATE_STAGE, log_generation, save_generation

__all__ = [
    "DEFAULT_MAX_SECONDS",
    "GENERATE_STAGE",
    "Output",
    "PromptPlanner",
    "action_frames",
    "check_free",
    "check_length",
    "check_prompted",
    "check_seconds",
    "edit",
    "edit_part",
    "generate",
    "generate_parts",
    "length_cap",
    "load_generator",
    "log_generation",
    "plan_output",
    "plan_parts",
    "require_words",
    "resolve_model_file",
    "save_generation",
    "seconds_range",
    "staged",
    "variations",
]
