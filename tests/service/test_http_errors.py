"""The one mapping from domain errors to HTTP statuses: every refusal the layers below the
API raise has a 4xx/5xx of its own, never the 500 of a bug."""
from __future__ import annotations

import inspect

import pytest

import service.errors as errors
from service.api.http_errors import status_of

EXPECTED = {
    errors.Unreadable: 400, errors.NotFound: 404, errors.Conflict: 409, errors.TooLarge: 413,
    errors.Invalid: 422, errors.Unavailable: 503, errors.StorageRefused: 507,
    errors.UnknownSystem: 404, errors.UnknownRecording: 404, errors.SpecConflict: 409,
    errors.DuplicateConflict: 409,
}


@pytest.mark.parametrize("cls", [c for _, c in inspect.getmembers(errors, inspect.isclass)
                                 if issubclass(c, errors.ServiceError)
                                 and c not in (errors.ServiceError, errors.StoreError)],
                         ids=lambda c: c.__name__)
def test_every_domain_error_has_its_status(cls: type[errors.ServiceError]) -> None:
    assert cls in EXPECTED, f"{cls.__name__}: add it to http_errors.STATUS and here"
    assert status_of(cls("what, where")) == EXPECTED[cls]


def test_an_unmapped_error_is_a_bug() -> None:
    assert status_of(errors.ServiceError("no class of its own")) == 500
