"""M2D2M's discrete diffusion: transition schedules (uniform β_t and dynamic β(t, d)), posteriors, loss."""

from m2d2m.diffusion.loss import DiffusionLoss, TimestepSampler, diffusion_loss
from m2d2m.diffusion.transition import (DISTANCES, KINDS, SCHEDULES, ScheduleConfig, TransitionSchedule,
                                        code_distances)

__all__ = ["DISTANCES", "KINDS", "SCHEDULES", "DiffusionLoss", "ScheduleConfig", "TimestepSampler",
           "TransitionSchedule", "code_distances", "diffusion_loss"]
