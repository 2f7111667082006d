"""experiments/calibration.py end to end in its smoke mode: the table has its rows and finite ratios (no statistical
assertion: three seeds per row say nothing about calibration)."""

import math
import re
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).parent.parent / "experiments" / "calibration.py"



def _script(name: str, path: Path):
    """The experiment script at ``path`` loaded as the module ``name`` (experiments/ is not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

def test_quick_table_has_rows_with_finite_ratios(tmp_path):
    out = tmp_path / "calibration.md"
    subprocess.run([sys.executable, str(SCRIPT), "--rows", "deformation,orbit", "--quick", "--cache",
                    str(tmp_path / "cache"), "--out", str(out)], check=True, capture_output=True, text=True,
                   timeout=300)
    rows = [line for line in out.read_text().splitlines() if line.startswith("| ") and "---" not in line][1:]
    labels = [row.split(" | ")[0].lstrip("| ") for row in rows]
    assert [label.split(":")[0] for label in labels] == ["deformation"] * 4 + ["orbit fit"] * 2
    for row in rows:
        found = re.search(r"\*\*([0-9.naninf]+)\*\*", row)
        assert found, row
        ratio = float(found.group(1))
        assert math.isfinite(ratio) and ratio > 0, row
    assert re.search(r"\d+/3 = ", rows[-2]), rows[-2]  # the orbit fit carries its global test over the 3 seeds
    assert (tmp_path / "cache" / "orbit" / "50000.pkl").exists()  # every realization cached


def test_group_test_is_the_drop_in_square_sum_when_the_group_may_be_biased():
    """sequence_block.group_test on a linear model y = A x + e (σ = 1): T = ṽᵀR⁻¹ṽ of the group's rows equals the
    square sum of all residuals less that of the adjustment without the group (the test of an arbitrary bias in
    it), and diag R is the group's redundancy numbers."""
    import numpy as np

    module = _script("sequence_block", SCRIPT.parent / "sequence_block.py")
    group_test = module.group_test

    rng = np.random.default_rng(3)
    design, group = rng.normal(size=(30, 4)), np.arange(6)
    observed = design @ rng.normal(size=4) + rng.normal(size=30)
    cofactor = np.linalg.inv(design.T @ design)
    residual = design @ (cofactor @ design.T @ observed) - observed
    others = design[6:]
    rest = others @ np.linalg.lstsq(others, observed[6:], rcond=None)[0] - observed[6:]
    statistic, count, redundancy = group_test(residual[group], design[group], cofactor)
    assert count == 6
    assert np.isclose(statistic, residual @ residual - rest @ rest, rtol=1e-10)
    hat = design @ cofactor @ design.T
    assert np.allclose(redundancy, 1.0 - np.diag(hat)[group])


def test_group_test_with_errors_the_weights_leave_out_is_chi_square():
    """With errors of the other observations that the weights leave out (y_o += B c, c ~ N(0, I)) and S their
    covariance of the estimates (Q A_oᵀ B Bᵀ A_o Q), T = ṽᵀ(R + J S Jᵀ)⁻¹ṽ has mean q (χ²(q)) over 2000 draws;
    without S it is larger."""
    import numpy as np

    module = _script("sequence_block", SCRIPT.parent / "sequence_block.py")

    rng = np.random.default_rng(5)
    design = rng.normal(size=(30, 4))
    shared = np.zeros((30, 2))
    shared[6:] = 3.0 * rng.normal(size=(24, 2))
    cofactor = np.linalg.inv(design.T @ design)
    gain = cofactor @ design.T @ shared
    systematic = gain @ gain.T
    stated, plain = [], []
    for _ in range(2000):
        observed = rng.normal(size=30) + shared @ rng.normal(size=2)
        residual = design @ (cofactor @ design.T @ observed) - observed
        stated.append(module.group_test(residual[:6], design[:6], cofactor, systematic)[0])
        plain.append(module.group_test(residual[:6], design[:6], cofactor)[0])
    assert abs(np.mean(stated) / 6 - 1) < 0.05
    assert np.mean(plain) / 6 > 1.2


def test_seed_list_takes_the_place_of_a_rows_fresh_seeds():
    """--seed-list: comma-separated seeds and inclusive ranges, in place of the row's own fresh seeds (the first
    --seeds of them); without it a row keeps its own."""
    module = _script("calibration", SCRIPT)

    given = module.parse_seeds("400-402, 53200,53205-53206")
    assert given == [400, 401, 402, 53200, 53205, 53206]
    assert module.seed_range("sequence", 4, given) == [400, 401, 402, 53200]
    assert module.seed_range("sequence", 3) == [400, 401, 402]
    assert module.seed_range("sequence_2", 2) == [400, 401]
    assert list(module.seed_range("orbit", 2)) == [50000, 50001]


def test_group_test_takes_the_rank_where_the_group_alone_fixes_an_unknown():
    """Where an unknown is fixed by the group's rows alone (the datum the sequences' ties leave free), R = I − J Q Jᵀ
    is singular: the group's residuals have none along that direction, T is taken on R's rank, q − 1, and its mean
    over 2000 draws is q − 1 (against χ²(q) it would read low)."""
    import numpy as np

    module = _script("sequence_block", SCRIPT.parent / "sequence_block.py")

    rng = np.random.default_rng(7)
    design = rng.normal(size=(30, 4))
    design[6:, 3] = 0.0  # the fourth unknown is seen by the group's six rows only
    cofactor = np.linalg.inv(design.T @ design)
    statistics = []
    for _ in range(2000):
        observed = rng.normal(size=30)
        residual = design @ (cofactor @ design.T @ observed) - observed
        statistic, count, _ = module.group_test(residual[:6], design[:6], cofactor)
        statistics.append(statistic)
    assert count == 5
    assert abs(np.mean(statistics) / 5 - 1) < 0.05
