"""``needlenet demo``, README's first command: the main job on its defaults."""

from __future__ import annotations

from needlenet.cli import main


def test_demo_writes_a_report_with_table_plots_and_animation(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert f"report: {out / 'report.md'}" in printed
    report = (out / "report.md").read_text()
    assert "## Headline metrics: learned against classical" in report
    for suite in ("inplane", "axial", "volume", "servo", "external"):
        assert (out / suite / "results.json").exists()
        assert f"| {suite} |" in report
    assert (out / "inplane_overlay.gif").stat().st_size > 10_000
    pngs = sorted(p.name for p in out.rglob("*.png"))
    assert len(pngs) >= 6
    for line in report.splitlines():  # every linked plot exists
        if line.startswith("!["):
            assert (out / line.split("](", 1)[1].rstrip(")")).exists(), line
    # a second run refuses to replace the report unless asked
    assert main(["demo", "--out", str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
