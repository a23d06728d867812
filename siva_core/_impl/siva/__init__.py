"""The SIVA estimator, one concept per module: ``estimator`` (:class:`Siva`, the run from
records to an identification), ``identification`` (:class:`Identification`, its result and
JSON form), ``recommend`` (Approach III and the refined ``best``: :func:`recommend_best`),
``bounds`` (candidates moved inside the physical bounds), ``output_error_training`` (the
second training phase), ``metrics`` (estimates on the records, baselines) and
``processing_choice`` (:func:`choose_processing`)."""
from .bounds import MovedCandidates, physical_candidates
from .estimator import Progress, Siva
from .identification import Identification
from .processing_choice import choose_processing
from .recommend import Recommendation, recommend_best

__all__ = ["Identification", "MovedCandidates", "Progress", "Recommendation", "Siva",
           "choose_processing", "physical_candidates", "recommend_best"]
