"""experiments/calibration.py end to end in its smoke mode: the table has its rows and finite ratios (no statistical
assertion: three seeds per row say nothing about calibration)."""

import math
import re
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).parent.parent / "experiments" / "calibration.py"


def test_quick_table_has_rows_with_finite_ratios(tmp_path):
    out = tmp_path / "calibration.md"
    subprocess.run([sys.executable, str(SCRIPT), "--rows", "deformation,orbit", "--quick", "--cache",
                    str(tmp_path / "cache"), "--out", str(out)], check=True, capture_output=True, text=True,
                   timeout=300)
    rows = [line for line in out.read_text().splitlines() if line.startswith("| ") and "---" not in line][1:]
    labels = [row.split(" | ")[0].lstrip("| ") for row in rows]
    assert [label.split(":")[0] for label in labels] == ["deformation"] * 4 + ["orbit fit"] * 2
    for row in rows:
        ratio = float(re.search(r"\*\*([0-9.naninf]+)\*\*", row).group(1))
        assert math.isfinite(ratio) and ratio > 0, row
    assert re.search(r"\d+/3 = ", rows[-2]), rows[-2]  # the orbit fit carries its global test over the 3 seeds
    assert (tmp_path / "cache" / "orbit" / "50000.pkl").exists()  # every realization cached
