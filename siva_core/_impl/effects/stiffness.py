"""Stiffness the nominal model lacks: a missing spring path, hardening/softening, asymmetry."""
from ._base import Effect, register_effect, sign_word

SPRING = register_effect(Effect(
    name="spring", kind="spring", family="linear stiffness",
    explanation=("a missing linear stiffness path: the natural frequencies are off by the "
                 "same amount on every record, so the phase error grows steadily in time."),
    magnitude="k"))

CUBIC_SPRING = register_effect(Effect(
    name="cubic_spring", kind="cubic_spring", family="hardening/softening stiffness",
    explanation=("a cubic stiffness (geometric or material nonlinearity): the frequency "
                 "shifts with the square of the amplitude, so the phase drifts on large "
                 "records and early in the decay, while small records are unaffected."),
    magnitude="k3",
    interpret=lambda c: sign_word(c.get("k3", 0.0), "Identified as hardening (k3 > 0).",
                                  "Identified as softening (k3 < 0).")))

QUADRATIC_SPRING = register_effect(Effect(
    name="quadratic_spring", kind="quadratic_spring", family="asymmetric stiffness",
    explanation=("an asymmetric (quadratic) stiffness, e.g. a pre-bent or one-sided "
                 "support: stiffer one way than the other, so the response gains even "
                 "harmonics and an offset that grow with amplitude."),
    magnitude="k2"))
