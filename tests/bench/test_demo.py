import csv

import pytest

from manualcontrol.bench import demo


def test_demo_runs_a_quick_suite_and_writes_its_report(tmp_path, capsys):
    assert demo.main(["--out", str(tmp_path), "--suite", "popovici2017", "--workers", "2"]) == 0
    folder = tmp_path / "popovici2017"
    with (folder / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 7 and {row["status"] for row in rows} == {"ok"}
    # remnant-free constant pilot: the filter explains u almost entirely
    constant = next(row for row in rows if row["batch"] == "constant")
    assert float(constant["vaf_one_step"]) > 99.5
    report = (folder / "report.md").read_text()
    assert "## constant-remnant" in report and "99.87 %" in report  # beside the paper's VAF
    assert (folder / "figures" / "constant.png").read_bytes().startswith(b"\x89PNG")
    assert "popovici2017/report.md" in (tmp_path / "README.md").read_text()
    assert "index:" in capsys.readouterr().out
    assert not list(tmp_path.rglob(".*part*"))  # no temporary debris


def test_a_failing_report_is_said_and_fails_the_demo(tmp_path, capfd, monkeypatch):
    def broken(suite, rows, out):
        raise RuntimeError("no figures today")

    monkeypatch.setattr(demo, "write_report", broken)
    assert demo.main(["--out", str(tmp_path), "--suite", "boer-kenyon1998"]) == 3
    printed = capfd.readouterr()  # the stream and the report child are processes
    assert "boer-kenyon1998: 6 runs, 0 failed (the report failed" in printed.out
    assert "boer-kenyon1998 (report failed)" in (tmp_path / "README.md").read_text()
    assert not (tmp_path / "boer-kenyon1998" / "report.md").exists()


def test_two_suites_in_two_streams_and_a_bad_worker_count(tmp_path, capfd):
    suites = ["--suite", "boer-kenyon1998", "--suite", "schiess-roland1975"]
    assert demo.main(["--out", str(tmp_path), *suites, "--workers", "2"]) == 0
    printed = capfd.readouterr().out
    for name, runs in (("boer-kenyon1998", 6), ("schiess-roland1975", 10)):
        assert f"{name}: {runs} runs, 0 failed ->" in printed
        assert (tmp_path / name / "report.md").is_file()
    index = (tmp_path / "README.md").read_text()
    assert index.index("boer-kenyon1998") < index.index("schiess-roland1975")
    for bad in ("0", "two"):
        with pytest.raises(SystemExit) as stop:
            demo.main(["--out", str(tmp_path / "bad"), "--workers", bad])
        assert stop.value.code == 2
        assert "argument --workers: must be" in capfd.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_a_stream_that_fails_still_reports_the_suites_it_finished(tmp_path, capfd, monkeypatch):
    run_suite = demo.run_suite

    def failing(suite, folder, **options):
        if suite.name == "boer-kenyon1998":
            raise OSError("disk full")
        return run_suite(suite, folder, **options)

    monkeypatch.setattr(demo, "run_suite", failing)
    suites = ["--suite", "boer-kenyon1998", "--suite", "schiess-roland1975"]
    # one stream runs both, the most runs first: schiess-roland1975, then the failure
    assert demo.main(["--out", str(tmp_path), *suites, "--workers", "1"]) == 3
    printed = capfd.readouterr()
    assert "OSError: disk full" in printed.err
    assert "schiess-roland1975: 10 runs, 0 failed ->" in printed.out
    assert "boer-kenyon1998: did not finish" in printed.out
    index = (tmp_path / "README.md").read_text()
    assert "[schiess-roland1975](schiess-roland1975/report.md): 10 runs, 0 failed" in index
    assert "boer-kenyon1998 (report failed)" in index
    assert (tmp_path / "schiess-roland1975" / "report.md").is_file()
