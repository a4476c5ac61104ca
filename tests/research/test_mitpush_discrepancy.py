"""`dbcslam_research.mitpush_discrepancy`: split selection, summary tables, usage errors."""

from __future__ import annotations

from pathlib import Path

import pytest

import dbcslam_research.mitpush_discrepancy as md


def _bag(shape: str, i: int) -> Path:
    return Path(f"/bags/motion_surface=abs_shape={shape}_a=0_v=20_i=0.000_s=0.{i}00_t=0.000")


def test_splits_are_shape_disjoint_and_reverse_each_other() -> None:
    (fa, ha), (fb, hb) = md.SPLITS["A"], md.SPLITS["B"]
    assert not set(fa) & set(ha)
    assert (fa, ha) == (hb, fb)


def test_round_split_alternates_pushes_of_the_same_objects() -> None:
    bags = [_bag(s, i) for s in ("ellip1", "ellip3", "hex") for i in range(5)]
    fit, held = md.split_bags(bags, "R", 1)
    assert len(fit) == 5 and len(held) == 5 and not set(fit) & set(held)
    assert {md._shape(b) for b in fit + held} == {"ellip1", "ellip3"}
    assert fit[:3] == [_bag("ellip1", 0), _bag("ellip1", 2), _bag("ellip1", 4)]
    assert held[:2] == [_bag("ellip1", 1), _bag("ellip1", 3)]
    fa, ha = md.split_bags(bags, "A", 1)
    assert {md._shape(b) for b in fa} == {"hex"} and len(ha) == 10


def test_subset_keeps_every_nth_push_of_each_shape() -> None:
    bags = [_bag(s, i) for s in ("hex", "rect1", "ellip1") for i in range(5)]
    got = md._subset(bags, ("rect1", "hex"), 2)
    assert [md._shape(b) for b in got] == ["rect1"] * 3 + ["hex"] * 3
    assert got[0] == _bag("rect1", 0) and got[1] == _bag("rect1", 2)


def test_markdown_tables_carry_the_numbers() -> None:
    model = {
        "train_loglik_by_noise_factor": {"1.0": 10.0, "3.0": 12.5},
        "noise_factor": 3.0,
        "heldout_loglik": 20.25,
        "heldout_pred_rmse_m": 0.0005,
        "heldout_track_rmse_m": 0.0004,
    }
    summary = {
        "settings": {"particles": 10},
        "splits": {
            "A": {
                "fit": ["rect1", "hex"],
                "heldout": ["ellip1", "ellip3"],
                "n_fit": 2,
                "n_heldout": 2,
                "models": {"quasi_static": model},
                "analysis": {
                    "quasi_static": {
                        "verdict": "none",
                        "params": {},
                        "stderr": {},
                        "gain": 1.0,
                        "loglik_gain": 0.0,
                        "tracking_gain": 1.0,
                    }
                },
            }
        },
    }
    text = md.markdown(summary)
    assert "| quasi_static | x3 | 12.5 | 20.2 | 0.500 | 0.400 |" in text
    assert "| A | quasi_static | none | - | 1.0 | 0.0 | 1.0 |" in text


def test_bad_usage_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert md.main(["--out", str(tmp_path), "--every", "0"]) == 2
    assert "--every" in capsys.readouterr().err
