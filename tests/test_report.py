"""Evaluation bookkeeping: errors, correctness, tables and the report from known results."""

from __future__ import annotations

import math

import pytest

from skyfix.report import (CaseResult, heading_vs_prior_rows, read_results_csv, reliability_rows,
                           sigma_coverage_rows, summary_rows, write_report_html,
                           write_results_csv)


def _case(set_, dx, dyaw, conf, scenario=1, status="ok", offset=0.0):
    return CaseResult(case=f"{set_}-{dx}", set=set_, scenario=scenario, truth_x=100.0, truth_y=200.0,
                      truth_yaw_deg=359.5, fix_x=100.0 + dx, fix_y=200.0, fix_grid_heading_deg=(359.5 + dyaw) % 360,
                      confidence=conf, status=status, prior_offset_m=offset, time_profile_s=1.0, time_locate_s=2.0)


def test_errors_wrap_heading_and_apply_scenario_tolerances():
    c = _case("REF", 3.0, 1.5, 0.9)
    assert c.position_error_m == pytest.approx(3.0)
    assert c.heading_error_deg == pytest.approx(1.5)  # across north: 359.5 -> 1.0
    assert c.correct  # scenario 1: 5 m, 2 deg
    assert not _case("REF", 6.0, 0.0, 0.9).correct
    assert not _case("REF", 0.5, 0.0, 0.9, scenario=2, status="no skyline").correct
    assert _case("REF", 50.0, 0.5, 0.9, scenario=3).correct  # heading only
    assert not _case("REF", 0.0, 1.5, 0.9, scenario=3).correct


def test_tables_count_what_they_say(tmp_path):
    rs = [_case("REF", 1.0, 0.1, 0.95), _case("REF", 20.0, 0.1, 0.95), _case("LREL", 2.0, 0.2, 0.5),
          _case("LREL", 0.0, 0.0, 0.1, status="error: x")]
    rows = {r["set"]: r for r in summary_rows(rs)}
    assert rows["REF"]["correct_pct"] == 50.0 and rows["REF"]["conf_ge_0.9"] == 2
    assert rows["REF"]["correct_if_conf_ge_0.9_pct"] == 50.0
    assert rows["LREL"]["failed"] == 1 and rows["all"]["cases"] == 4
    rel = reliability_rows(rs)
    assert sum(r["cases"] for r in rel) == 4
    top = rel[-1]
    assert top["cases"] == 2 and top["observed_correct"] == 0.5
    path = write_results_csv(rs, tmp_path / "results.csv")
    back = read_results_csv(path)
    assert [b.correct for b in back] == [r.correct for r in rs]
    assert back[1].position_error_m == pytest.approx(20.0)
    page = write_report_html(tmp_path, title="t", intro="i", sections=[("s", "<p>x</p>")], figures=[],
                             command="skyfix evaluate")
    from skyfix import __version__

    assert "skyfix evaluate" in page.read_text() and f"skyfix {__version__}" in page.read_text()


def test_sigma_coverage_counts_errors_within_one_and_two_sigmas():
    """Errors 1, 3 and 20 m against 2 m sigmas: 1 of 3 within 1 sigma, 2 of 3 within 2; the
    misregistration is taken off first; a failed case and a missing sigma do not count."""
    from dataclasses import replace

    rs = [replace(_case("DEMERR", dx, dyaw, 0.5), position_sigma_m=2.0, heading_sigma_deg=0.1)
          for dx, dyaw in ((1.0, 0.05), (3.0, 0.15), (20.0, 0.5))]
    rs.append(replace(_case("DEMERR", 6.0, 0.0, 0.5), position_sigma_m=2.0, heading_sigma_deg=0.1,
                      map_offset_x_m=5.0))  # 6 m from the truth, 1 m from where the map puts it
    rs.append(replace(_case("DEMERR", 0.0, 0.0, 0.5, status="no skyline"), position_sigma_m=2.0))
    rs.append(_case("REF", 0.0, 0.0, 0.9))  # no sigmas reported
    rows = {r["set"]: r for r in sigma_coverage_rows(rs)}
    d = rows["DEMERR"]
    assert d["pos_cases"] == 4 and d["head_cases"] == 4
    assert d["pos_within_1_sigma_pct"] == 50.0 and d["pos_within_2_sigma_pct"] == 75.0
    assert d["head_within_1_sigma_pct"] == 50.0 and d["head_within_2_sigma_pct"] == 75.0
    assert rows["REF"]["pos_cases"] == 0 and math.isnan(rows["REF"]["pos_within_1_sigma_pct"])
    assert rows["all"]["pos_cases"] == 4
    from skyfix.report import header_label

    assert header_label("pos_within_1_sigma_pct") == "position within 1 sigma [%]"


def test_report_headers_and_cases_read_as_words():
    from skyfix.report import case_rows, figure_caption, format_table, header_label

    assert header_label("head_err_med_deg") == "heading error median [deg]"
    assert header_label("correct_if_conf_ge_0.9_pct") == "correct if confidence >= 0.9 [%]"
    assert header_label("cases") == "cases"
    rows = case_rows([_case("REF", 3.0, 1.5, 0.9), _case("REF", 6.0, 0.0, 0.2)])
    assert [r["correct"] for r in rows] == ["yes", "no"]
    assert rows[0]["position_error_m"] == pytest.approx(3.0)
    page = format_table(rows, "html")
    assert "<th>position error [m]</th>" in page and "position_error_m" not in page
    assert figure_caption("overlay_REF_case_001.png").endswith("(REF case 001)")


def test_heading_vs_prior_groups_by_offset():
    rs = [_case("REF", 0, 0.5, 0.9, scenario=3, offset=10.0), _case("REF", 0, 1.5, 0.9, scenario=3, offset=10.0),
          _case("REF", 0, 0.2, 0.9, scenario=3, offset=20.0)]
    rows = heading_vs_prior_rows(rs)
    assert [r["prior_offset_m"] for r in rows] == [10.0, 20.0]
    assert rows[0]["within_1deg_pct"] == 50.0 and rows[0]["within_2deg_pct"] == 100.0
    assert math.isclose(rows[1]["head_err_med_deg"], 0.2, abs_tol=1e-9)


def test_atomic_writes_leave_files_with_the_usual_permissions(tmp_path):
    """Outputs are written through a private temporary file; the result must not stay private
    (0600) but get the mode a plain open() gives under the process's umask."""
    import os

    from skyfix._io import write_json

    umask = os.umask(0)
    os.umask(umask)
    write_json(tmp_path / "a.json", {"x": 1})
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o666 & ~umask


def test_results_csv_gives_both_norths_and_reads_an_older_file(tmp_path):
    """fix_heading_deg is from true north (grid + convergence at the fix), truth_heading_deg too;
    a results.csv written before these columns (its fix_heading_deg the grid one) reads back
    with the same heading error."""
    import csv

    c = CaseResult(case="c", set="REF", scenario=2, truth_x=0.0, truth_y=0.0, truth_yaw_deg=240.75,
                   truth_meridian_convergence_deg=-14.05, fix_x=0.1, fix_y=0.0,
                   fix_grid_heading_deg=240.8, meridian_convergence_deg=-14.0)
    assert c.fix_heading_deg == pytest.approx(226.8) and c.truth_heading_deg == pytest.approx(226.7)
    assert c.heading_error_deg == pytest.approx(0.05)  # grid vs grid, not 0.1 across positions
    assert math.isnan(CaseResult(case="c", set="REF", scenario=2, truth_x=0.0, truth_y=0.0,
                                 truth_yaw_deg=1.0).fix_heading_deg)
    path = write_results_csv([c], tmp_path / "results.csv")
    (row,) = list(csv.DictReader(open(path)))
    assert (float(row["fix_heading_deg"]), float(row["fix_grid_heading_deg"]),
            float(row["meridian_convergence_deg"])) == (226.8, 240.8, -14.0)
    assert (float(row["truth_heading_deg"]), float(row["truth_yaw_deg"])) == (226.7, 240.75)
    assert read_results_csv(path)[0].heading_error_deg == pytest.approx(0.05)
    old = tmp_path / "old.csv"
    old.write_text("case,set,scenario,truth_x,truth_y,truth_yaw_deg,fix_x,fix_y,fix_heading_deg,status\n"
                   "c,REF,2,0,0,240.75,0.1,0,240.78,ok\n")
    (back,) = read_results_csv(old)
    assert back.fix_grid_heading_deg == 240.78 and back.heading_error_deg == pytest.approx(0.03)


def test_every_table_counts_the_error_beyond_the_misregistration():
    """A map shifted 3 m east and a fix 0.3 m from where the map puts the truth: 0.3 m in every
    table, figure and calibration line, as "correct" (within 1 m) counts it; results.csv keeps
    the plain 3.3 m beside it. The summary said 3.3 m against a 1 m bar for a case it called
    correct."""
    from dataclasses import replace

    from skyfix.evaluate import calibration_row
    from skyfix.report import case_rows

    r = replace(_case("DEMERR", 3.3, 0.1, 0.95, scenario=2), map_offset_x_m=3.0)
    assert r.correct and r.position_error_m == pytest.approx(3.3)
    row = summary_rows([r])[0]
    assert row["pos_err_med_m"] == pytest.approx(0.3) and row["err_x_med_m"] == pytest.approx(0.3)
    assert row["pos_err_p95_m"] == pytest.approx(0.3) and row["err_y_med_m"] == pytest.approx(0.0)
    assert case_rows([r])[0]["position_error_m"] == pytest.approx(0.3)

    class Dem:
        source = "/x/sierra.tif"

    line = calibration_row(r, {"log_ratio": 1.0}, Dem())
    assert line["err"] == pytest.approx(0.3) and line["correct"] is True


def test_scenario_3_has_no_position_columns_and_counts_failures_at_their_offset():
    """Scenario 3's position is the rough one it was given (its drawn offset), not a result; a
    case that failed counts in its offset's cases as within neither bar (the 20 m row read
    0 cases and the 10 m row 100 % with one of two failed)."""
    rs = [_case("REF", 10.0, 0.5, 0.9, scenario=3, offset=10.0),
          _case("REF", 10.0, 0.0, 0.1, scenario=3, offset=10.0, status="no skyline"),
          _case("REF", 20.0, 0.0, 0.1, scenario=3, offset=20.0, status="no skyline")]
    row = summary_rows(rs)[0]
    assert all(math.isnan(row[k]) for k in ("err_x_med_m", "pos_err_med_m", "pos_err_p95_m"))
    by = {r["prior_offset_m"]: r for r in heading_vs_prior_rows(rs)}
    assert by[10.0]["cases"] == 2 and by[10.0]["failed"] == 1
    assert by[10.0]["within_1deg_pct"] == 50.0 and by[10.0]["head_err_med_deg"] == pytest.approx(0.5)
    assert by[20.0]["cases"] == 1 and by[20.0]["within_2deg_pct"] == 0.0


def test_the_error_cdf_shows_errors_below_a_tenth_of_a_metre(tmp_path, monkeypatch):
    """A set whose errors all lay under 0.1 m had no visible curve (the axis started there)."""
    pytest.importorskip("matplotlib")
    import skyfix.report as report

    seen = {}

    def keep(fig, path):
        seen["xlim"] = fig.axes[0].get_xlim()
        seen["lines"] = [ln.get_xdata() for ln in fig.axes[0].get_lines()]
        return path

    monkeypatch.setattr(report, "save_figure", keep)
    cases = [_case("OCCL", dx, 0.0, 0.9, scenario=2) for dx in (0.012, 0.03, 0.06)]
    cases.append(_case("OCCL", 0.5, 0.0, 0.9, scenario=2, status="no skyline"))
    report.plot_error_cdfs(cases, tmp_path / "cdf.png", 2)
    assert seen["xlim"][0] == pytest.approx(0.01)
    xs = seen["lines"][0]
    assert xs[0] == pytest.approx(0.01) and min(xs[1:]) == pytest.approx(0.012)


def test_memory_has_its_own_table_and_times_theirs():
    from skyfix.report import memory_rows, timing_rows

    cases = [_case("REF", 1.0, 0.0, 0.9), _case("REF", 1.0, 0.0, 0.9)]
    cases[0].peak_rss_mb, cases[1].peak_rss_mb = 300.0, 420.0
    assert all(r["stage"] != "" and "RSS" not in r["stage"] for r in timing_rows(cases, 1))
    assert memory_rows(cases)[0]["max_mb"] == pytest.approx(420.0)


def test_evaluate_overwrite_removes_the_earlier_runs_outputs_only(tmp_path):
    from skyfix.evaluate import clear_outputs

    for name in ("overlay_REF_case_000.png", "results.csv", "report.html", "notes.txt"):
        (tmp_path / name).write_text("x")
    (tmp_path / "cases" / "REF").mkdir(parents=True)
    clear_outputs(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
