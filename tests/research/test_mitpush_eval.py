"""The measured-data pipeline (dbcslam_research.mitpush_eval) on the 3 pushes in tests/data."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import pytest

from dbcslam_research.mitpush_eval import (
    EvalOptions,
    markdown_table,
    resolve_data,
    run_eval,
    summarise,
)
from dbcslam_ros.errors import UsageError

DATA = Path(__file__).resolve().parents[1] / "data" / "mit-push"


@pytest.fixture(scope="module")
def result(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path, str]:
    out = tmp_path_factory.mktemp("mitpush_eval")
    progress = io.StringIO()
    summary = run_eval(
        EvalOptions(
            data=DATA,
            out=out / "table",
            work=out / "work",
            particles=16,
            jobs=1,
            progress=progress,
            params=(("use_pusher_wrench", "false"),),
        ),
        command="test",
    )
    return summary, out, progress.getvalue()


def test_writes_table_json_and_one_figure_per_shape(
    result: tuple[dict[str, Any], Path, str],
) -> None:
    summary, out, progress = result
    table = out / "table"
    md = (table / "mitpush.md").read_text()
    on_disk = json.loads((table / "mitpush.json").read_text())
    assert on_disk["groups"] == json.loads(json.dumps(summary["groups"]))
    shapes = {"ellip1", "hex", "rect1"}
    assert {p["shape"] for p in on_disk["pushes"]} == shapes
    assert {Path(f).name for f in on_disk["figures"]} == {f"mitpush_{s}.png" for s in shapes}
    assert not Path(on_disk["settings"]["data"]).is_absolute()  # no machine paths in reports
    for f in on_disk["figures"]:
        assert (table / f).stat().st_size > 10_000  # names relative to the table directory
    for name in (*shapes, "ft_flag", "overall"):
        assert f"| {name} |" in md
    assert "[3/3]" in progress and "contact agreement" in progress
    assert summary["settings"]["filter_uses_pusher_wrench"] is False
    # rect1's F/T stream is stale: its flag is geometric, the others' from the F/T sensor
    sources = {p["shape"]: p["contact_source"] for p in on_disk["pushes"]}
    assert sources == {"ellip1": "ft", "hex": "ft", "rect1": "geometry"}


def test_metrics_are_in_range(result: tuple[dict[str, Any], Path, str]) -> None:
    summary, _, _ = result
    for push in summary["pushes"]:
        m = push["metrics"]
        assert m["matched"] == m["estimates"] > 50
        assert 0.0 <= m["contact_flag_agreement"] <= 1.0
        assert m["contact_flag_entries"] == m["matched"]
        for key in ("position_rmse_m", "yaw_rmse_rad"):
            assert math.isfinite(m[key]) and m[key] > 0.0
        # RMSE relative to the *added* noise (5 mm / 0.05 rad)
        assert m["position_rmse_over_noise"] == pytest.approx(
            m["position_rmse_m"] / 0.005, rel=1e-3
        )
        assert m["yaw_rmse_over_noise"] == pytest.approx(m["yaw_rmse_rad"] / 0.05, rel=1e-3)
        pairs = {f["pair"]: f for f in m["friction"]}
        assert set(pairs) == {"pusher", "surface"}
        for f in pairs.values():
            assert sum(f["final_posterior"]) == pytest.approx(1.0, abs=1e-3)
            assert min(f["candidates"]) <= f["posterior_mean"] <= max(f["candidates"])
    overall = summary["groups"]["overall"]
    assert overall["pushes"] == 3
    assert 0.0 <= overall["contact_flag_agreement"] <= 1.0
    assert isinstance(overall["pass_pose"], bool) and isinstance(overall["pass_contact"], bool)


def test_reuse_reevaluates_the_same_replays(
    result: tuple[dict[str, Any], Path, str], tmp_path: Path
) -> None:
    summary, out, _ = result
    again = run_eval(
        EvalOptions(data=DATA, out=tmp_path, work=out / "work", reuse=True, figures=False)
    )
    assert again["groups"] == summary["groups"]
    assert again["settings"]["particles"] == 16
    assert again["settings"]["filter_uses_pusher_wrench"] is False
    assert "re-evaluated" in (tmp_path / "mitpush.md").read_text()
    for push in summary["pushes"]:
        assert 0.0 <= push["metrics"]["contact_flag_agreement_touch"] <= 1.0


def test_summary_medians_and_pass_flags() -> None:
    def push(shape: str, pos: float, agree: float) -> dict[str, Any]:
        metrics = {
            "position_rmse_over_noise": pos,
            "yaw_rmse_over_noise": 0.5,
            "contact_flag_agreement": agree,
            "friction": [
                {
                    "pair": "pusher",
                    "candidates": [0.1, 0.3],
                    "final_posterior": [1.0, 0.0],
                    "posterior_mean": 0.1,
                }
            ],
        }
        return {"shape": shape, "contact_source": "ft", "metrics": metrics}

    groups = summarise([push("a", 0.2, 0.95), push("a", 0.4, 0.5), push("b", 0.9, 0.97)])
    assert groups["a"]["position_rmse_over_noise"] == pytest.approx(0.3)
    assert groups["a"]["pass_pose"] and not groups["a"]["pass_contact"]
    assert not groups["b"]["pass_pose"] and groups["b"]["pass_contact"]
    assert groups["overall"]["contact_flag_agreement"] == pytest.approx(0.95)
    assert groups["overall"]["pass_pose"] and groups["overall"]["pass_contact"]
    assert groups["overall"]["friction"]["pusher"]["final_posterior_average"] == [1.0, 0.0]
    assert "ft_flag" not in groups
    assert groups["overall"]["pushes_over_noise"] == 0
    assert "| overall | 3 (0) |" in markdown_table({"groups": groups})
    # tracking failures (pose RMSE above the added noise) are counted, not hidden
    worse = summarise([push("a", 0.2, 0.95), push("a", 1.4, 0.5), push("a", 0.3, 0.9)])
    assert worse["a"]["pushes_over_noise"] == 1
    assert worse["a"]["position_rmse_over_noise"] == pytest.approx(0.3)


def test_missing_data_is_a_usage_error(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="--data"):
        resolve_data(tmp_path / "nowhere")
    with pytest.raises(UsageError, match=r"no \.h5"):
        resolve_data(tmp_path)
    assert len(resolve_data(DATA)) == 3


def test_default_data_is_the_shared_copy_beside_the_repository() -> None:
    from dbcslam_research.mitpush_eval import DEFAULT_DATA

    repo = Path(__file__).resolve().parents[2]
    assert repo.parent / "shared" / "data" / "mit-push" == DEFAULT_DATA


def test_select_shapes_keeps_the_named_shapes_and_names_missing_ones() -> None:
    from dbcslam_research.mitpush_eval import select_shapes

    files = [
        Path(f"motion_surface=abs_shape={s}_a=0_v=10_i=0.000_s=0.{i}_t=0.000.h5")
        for s in ("ellip1", "hex", "ellip3")
        for i in range(2)
    ]
    assert select_shapes(files, None) == files
    got = select_shapes(files, ("ellip1", "ellip3"))
    assert [f.name.split("shape=")[1][:6] for f in got] == ["ellip1"] * 2 + ["ellip3"] * 2
    with pytest.raises(UsageError, match="rect1"):
        select_shapes(files, ("rect1",))
