"""SIVA training (paper Sec. 2.4), one concept per module: ``trainer`` (the adversarial
loop, :class:`SivaTrainer`), ``settings`` (:class:`SivaSettings`, :class:`EpochLog`),
``pools`` (the equation-error phase's samples), ``output_error_phase`` (the linearised
output error of the second phase), ``initial_guess`` (where the generator starts) and
``scores`` (the discriminator's verdict per validation record)."""
from .initial_guess import least_squares_guess
from .settings import EpochLog, SivaSettings
from .trainer import SivaTrainer

__all__ = ["EpochLog", "SivaSettings", "SivaTrainer", "least_squares_guess"]
