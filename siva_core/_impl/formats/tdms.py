"""National Instruments TDMS (``.tdms``), read and written with npTDMS.

Channel mapping: every channel of every group, by channel name (a name found in two groups
is refused, unless ``channel_map`` names it as ``"group/channel"``).  ``time`` is a channel
named ``time`` when there is one, else the waveform properties of the first kept channel:
``time = wf_start_offset + i * wf_increment`` (what LabVIEW writes for waveforms).  The
``unit_string`` property is the unit hint (checked like a CSV unit hint) unless the channel
was renamed.  Only kept channels are read, after checking their declared size.
"""
from __future__ import annotations

import io

import numpy as np

from ._base import (ColumnSelector, Columns, Format, ReadLimits, RecordingError, RecordLike,
                    SI_UNIT, register_format, split_unit)

MAGIC = b"TDSm"


def read_tdms(raw: bytes, name: str, select: ColumnSelector, limits: ReadLimits) -> Columns:
    from nptdms import TdmsFile

    try:
        tdms = TdmsFile.open(io.BytesIO(raw))  # metadata only; channels read on demand
    except Exception as exc:  # noqa: BLE001 - npTDMS raises anything on a malformed file
        raise RecordingError(f"{name}: not a readable TDMS file ({type(exc).__name__}: "
                             f"{str(exc)[:200]})") from None
    with tdms:
        channels = [(g.name, ch) for g in tdms.groups() for ch in g.channels()]
        limits.check_members("TDMS channels", len(channels), name)
        kept: dict[str, tuple[str, object]] = {}
        for group, ch in channels:
            qualified = f"{group}/{ch.name}"
            key = qualified if qualified in select.channel_map else ch.name
            target = select.target(key)
            if target is None:
                continue
            unit = str(ch.properties.get("unit_string", "") or "").strip()
            target = select.labelled(key, target, unit)
            if split_unit(target)[0] in {split_unit(t)[0] for t in kept}:
                raise RecordingError(f"{name}: channel {ch.name!r} appears in more than one "
                                     "group; name one as 'group/channel' in the channel map")
            kept[target] = (qualified, ch)
        total = values = 0
        for target, (qualified, ch) in kept.items():
            itemsize = getattr(getattr(ch, "dtype", None), "itemsize", 8) or 8
            total += len(ch) * itemsize
            values += len(ch)
        limits.check_total(f"{len(kept)} TDMS channel(s)", total, name)
        limits.check_values(values, name)
        if total > len(raw):  # TDMS is not compressed: the data must be in the file
            raise RecordingError(f"{name}: the TDMS channels declare {total} bytes of data, "
                                 f"more than the file's {len(raw)} bytes")
        data: dict[str, np.ndarray] = {}
        first = None
        for target, (qualified, ch) in kept.items():
            try:
                y = np.asarray(ch[:])
            except Exception as exc:  # noqa: BLE001
                raise RecordingError(f"{name}: channel {qualified!r}: unreadable "
                                     f"({type(exc).__name__}: {exc})") from None
            if y.dtype.kind not in "biuf":
                raise RecordingError(f"{name}: channel {qualified!r} has data type "
                                     f"{y.dtype}, expected real numbers")
            data[target] = y.astype(float)
            if first is None and split_unit(target)[0] != "time":
                first = ch
    if first is not None and not any(split_unit(t)[0] == "time" for t in data):
        inc = first.properties.get("wf_increment")
        if inc is None or not float(inc) > 0:
            raise RecordingError(f"{name}: no 'time' channel and no wf_increment property "
                                 f"on channel {first.name!r}")
        start = float(first.properties.get("wf_start_offset", 0.0))
        data["time"] = start + float(inc) * np.arange(len(data[next(iter(data))]))
    return Columns(data)


def write_tdms(rec: RecordLike) -> bytes:
    """Group ``recording``, one waveform channel per column (wf_increment, unit_string)."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    dt = float((rec.time[-1] - rec.time[0]) / (len(rec.time) - 1))
    buf = io.BytesIO()
    with TdmsWriter(buf) as writer:
        objs = [RootObject({"name": str(rec.name)}), GroupObject("recording")]
        for col, y in rec.channels.items():
            objs.append(ChannelObject("recording", col, np.asarray(y, dtype=float), properties={
                "wf_start_offset": float(rec.time[0]), "wf_increment": dt,
                "unit_string": SI_UNIT.get(col.partition("_")[0], "")}))
        writer.write_segment(objs)
    return buf.getvalue()


FORMAT = register_format(Format(
    "tdms", (".tdms",), read_tdms, write_tdms, media_types=("application/x-tdms",),
    sniff=lambda raw: raw[:4] == MAGIC, description="NI TDMS (npTDMS)"))
