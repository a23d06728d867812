"""What a route needs, declared in its signature (FastAPI ``Annotated`` dependencies):
the service (``ServiceDep``), its settings (``SettingsDep``), one system's trainer handle
(``SystemDep``: 404 for an unknown system, 409 for one whose stored spec is invalid) and
a checked system name (``Name``).  Routes never look the service up by hand."""
from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from ..errors import Invalid
from ..fleet.executor import TrainerHandle
from ..settings import Settings
from ..storage.store import NAME_RE
from ..systems import SivaService


def get_service(request: Request) -> SivaService:
    """The ``SivaService`` of this app (``create_app`` puts it in ``app.state``)."""
    return request.app.state.service


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


ServiceDep = Annotated[SivaService, Depends(get_service)]
SettingsDep = Annotated[Settings, Depends(get_settings)]


def check_name(name: str) -> str:
    """A system name as the store accepts it (also a directory name), else 422."""
    if not NAME_RE.fullmatch(name):
        raise Invalid(f"system name {name!r}: use 1-64 letters, digits, '_', '.' or '-', "
                      "starting with a letter or digit")
    return name


Name = Annotated[str, Depends(check_name)]


def get_system(name: str, service: ServiceDep) -> TrainerHandle:
    """The trainer handle of system ``name`` (the path parameter)."""
    return service.worker(name)


SystemDep = Annotated[TrainerHandle, Depends(get_system)]


def media_type(request: Request) -> str:
    """The request's Content-Type without parameters, lower case ('' when absent)."""
    return request.headers.get("content-type", "").split(";")[0].strip().lower()
