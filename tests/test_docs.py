"""The project's own docs carry the outward contract (docs/contract.md)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_docs_contract_holds_the_shared_contract_verbatim():
    # next to the reference data (SIVA_SHARED_DATA=<shared>/data), else ../shared
    data = os.environ.get("SIVA_SHARED_DATA")
    shared = Path(os.environ.get("SIVA_CONTRACT") or
                  ((Path(data).parent if data else ROOT.parent / "shared") / "CONTRACT.md"))
    if not shared.is_file():
        pytest.skip("the shared CONTRACT.md is not next to the repository")
    ours = (ROOT / "docs" / "contract.md").read_text()
    assert shared.read_text().strip() in ours, "docs/contract.md is out of sync with CONTRACT.md"
    head, _, ext = ours.partition("## Extensions")
    assert ext, "docs/contract.md: no Extensions section"


def test_docs_contract_lists_every_registered_format():
    from siva_core import RECORDING_FORMATS as REGISTRY

    ext = (ROOT / "docs" / "contract.md").read_text().partition("## Extensions")[2]
    for fmt in REGISTRY.values():
        assert f"`{fmt.suffixes[0]}`" in ext, fmt.name
        for media in fmt.media_types[:1]:
            assert f"`{media}`" in ext, (fmt.name, media)
