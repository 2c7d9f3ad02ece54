"""Reading contact-sensor recordings (the multi-view capture paper, A2): a CSV with a time column and one column
of raw analog readings (an Arduino's 10-bit ADC: 0-1023) per force-sensitive resistor.

    time_ms,left_hand,right_hand,left_foot:heel,left_foot:toe,right_foot
    0,12,9,15,20,14
    10,11,10,16,22,15
    ...

* the first column is time; its unit comes from the header (`time`/`time_s`: seconds,
  `time_ms`/`millis`: milliseconds, `time_us`/`micros`: microseconds) or `time_unit=`;
  it must increase strictly (sample at most every 1 ms with `millis()`, or use `micros()`);
* every other header names the body joint its sensor labels: a joint of the `body+index1`
  joint set (`left_foot` is the toe joint, `left_ankle` the ankle, `left_wrist` ...), or an
  alias (`left_hand` -> wrist, `left_heel` -> ankle, `left_toe` -> toe joint), optionally
  followed by `:label` to tell several sensors on one joint apart (`left_foot:toe`);
  `joints=[...]` maps the columns instead, in column order;
* delimiter `,` (or `;` / tab, taken from the header line); blank lines and lines starting
  with `#` are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from motiongen.errors import ConfigError, DataError
from motiongen.skeleton import JOINT_SETS

JOINT_NAMES = JOINT_SETS["body+index1"].names
ALIASES = {"left_hand": "left_wrist", "right_hand": "right_wrist", "left_heel": "left_ankle",
           "right_heel": "right_ankle", "left_toe": "left_foot", "right_toe": "right_foot",
           "left_toes": "left_foot", "right_toes": "right_foot"}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6}
DELIMITERS = (",", ";", "\t")


@dataclass
class SensorRecording:
    path: str
    time: np.ndarray          # (N,) float64 seconds, strictly increasing
    values: np.ndarray        # (N, C) float64 raw ADC counts in [0, adc_max]
    channels: list[str]       # (C,) column headers
    joints: list[str]         # (C,) the body joint each channel labels
    time_unit: str            # "s" | "ms" | "us", as read
    adc_max: int

    @property
    def rate(self) -> float:
        """Median sampling rate, Hz."""
        return float(1.0 / np.median(np.diff(self.time))) if len(self.time) > 1 else float("nan")

    def channel_index(self, name: str) -> int:
        """Column index of a channel, by its header or, when unambiguous, its joint."""
        if name in self.channels:
            return self.channels.index(name)
        hits = [i for i, j in enumerate(self.joints) if j == ALIASES.get(name, name)]
        if len(hits) == 1:
            return hits[0]
        raise ConfigError(f"no sensor channel {name!r}" + (" (several channels label this joint: name the column)"
                                                          if hits else f"; channels: {', '.join(self.channels)}"))


def channel_joint(header: str, path: str = "") -> str:
    """The body joint a column header names ('left_foot:toe' -> 'left_foot', 'left_hand' ->
    'left_wrist')."""
    base = header.split(":", 1)[0].strip().lower()
    base = ALIASES.get(base, base)
    if base not in JOINT_NAMES:
        raise DataError(path, header, "column header names no body joint: expected '<joint>' or '<joint>:<label>' "
                                      f"with a joint of {', '.join(JOINT_NAMES)} or an alias "
                                      f"({', '.join(ALIASES)}); or pass joints=[...]")
    return base


def time_unit_of(header: str, given: str = "auto") -> str:
    if given != "auto":
        if given not in TIME_UNITS:
            raise ConfigError(f"time_unit={given!r}: expected auto, s, ms or us")
        return given
    h = header.strip().lower()
    if h.endswith("_ms") or h in ("ms", "millis"):
        return "ms"
    if h.endswith("_us") or h in ("us", "micros"):
        return "us"
    return "s"


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _first_bad_line(path: str, delim: str, ncols: int) -> str:
    """Why np.loadtxt refused the file: the first line with the wrong count or a non-number."""
    with open(path, encoding="utf-8", errors="replace") as f:
        next(f)
        for lineno, line in enumerate(f, start=2):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = s.split(delim)
            if len(parts) != ncols:
                return f"line {lineno} has {len(parts)} values, the header names {ncols} columns"
            for k, p in enumerate(parts):
                if not _is_number(p):
                    return f"line {lineno} column {k + 1}: {p.strip()!r} is not a number"
    return "unreadable numbers"


def read_sensor_csv(path: str | Path, time_unit: str = "auto", adc_max: int = 1023,
                    joints: list[str] | None = None) -> SensorRecording:
    """Read and validate a recording (module doc). Raises DataError naming the file, the
    column and the line."""
    path = str(path)
    if not Path(path).is_file():
        raise DataError(path, None, "sensor recording does not exist")
    with open(path, encoding="utf-8", errors="replace") as f:
        header_line = f.readline().strip()
    delim = next((d for d in DELIMITERS if d in header_line), ",")
    header = [h.strip() for h in header_line.split(delim)]
    if len(header) < 2 or not header[0]:
        raise DataError(path, "header", f"expected a header line 'time,<sensor>,...' with at least one sensor, "
                                        f"found {header_line[:80]!r}")
    if _is_number(header[0]):
        raise DataError(path, "header", "the first line is numbers: the file needs a header line 'time,<sensor>,...'")
    channels = header[1:]
    if len(set(channels)) != len(channels):
        dup = next(c for c in channels if channels.count(c) > 1)
        raise DataError(path, dup, "two columns have this header")
    if joints is not None:
        if len(joints) != len(channels):
            raise ConfigError(f"joints=[...] names {len(joints)} joints, the file has {len(channels)} sensor columns")
        names = [channel_joint(j, "joints=") for j in joints]
    else:
        names = [channel_joint(c, path) for c in channels]
    unit = time_unit_of(header[0], time_unit)
    try:
        data = np.loadtxt(path, delimiter=delim, skiprows=1, ndmin=2, dtype=np.float64, comments="#")
    except ValueError:
        raise DataError(path, None, _first_bad_line(path, delim, len(header))) from None
    if data.shape[0] < 2:
        raise DataError(path, None, f"expected at least 2 samples, found {data.shape[0]}")
    if data.shape[1] != len(header):
        raise DataError(path, None, f"rows have {data.shape[1]} values, the header names {len(header)} columns")
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise DataError(path, header[c], f"non-finite value at line {r + 2}")
    t = data[:, 0] * TIME_UNITS[unit]
    step = np.diff(t)
    if (step <= 0).any():
        r = int(np.argmax(step <= 0)) + 1
        raise DataError(path, header[0], f"time must increase strictly: line {r + 2} ({data[r, 0]:g}) does not "
                                         f"follow line {r + 1} ({data[r - 1, 0]:g})")
    values = data[:, 1:]
    out = (values < 0) | (values > adc_max)
    if out.any():
        r, c = np.argwhere(out)[0]
        raise DataError(path, channels[c], f"line {r + 2}: reading {values[r, c]:g} is outside the ADC range "
                                           f"0..{adc_max} (pass adc_max= for another converter)")
    return SensorRecording(path, t, values, channels, names, unit, int(adc_max))
