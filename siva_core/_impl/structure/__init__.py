"""The model of a vibrating structure, one concept per module: ``model``
(:class:`Structure`: parameters, force inputs and the batched equation of motion),
``parts`` (elements, parameter settings, :class:`SpecError`), ``spec`` (reading and
checking a model spec), ``channels`` (its ``[channels]`` table) and ``modes`` (the
linearised model's frequencies and damping)."""
from .model import Structure
from .parts import GROUND, Element, ParameterInfo, SpecError

__all__ = ["GROUND", "Element", "ParameterInfo", "SpecError", "Structure"]
