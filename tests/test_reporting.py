"""The reporting home: one Markdown table helper, one figure saver at one DPI, one atomic CSV
writer, one mean ± std over seeds, one colour per model, and a machine stamp whose load average
never raises."""

from __future__ import annotations

import csv
import math
import os
import re
import statistics
import struct
from pathlib import Path

import pytest

import slungload
from slungload import reporting
from slungload.models.prediction import PHYSICS


def test_markdown_table_writes_header_rule_and_rows():
    text = reporting.markdown_table(["a", "b"], [[1, "x"], [None, 2.5]])
    assert text == "| a | b |\n|---|---|\n| 1 | x |\n| - | 2.5 |"
    assert reporting.markdown_table(["only"], []) == "| only |\n|---|"


def test_save_figure_writes_a_png_at_the_one_dpi(tmp_path):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2.0, 1.0))
    fig.add_subplot().plot([0, 1])
    path = reporting.save_figure(fig, tmp_path / "sub" / "f.png")
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", head[16:24])
    assert (width, height) == (2 * reporting.DPI, 1 * reporting.DPI)
    assert [p.name for p in path.parent.iterdir()] == ["f.png"]  # no temporary file left


def test_only_the_reporting_home_saves_figures_or_sets_a_dpi():
    package = Path(slungload.__file__).parent
    found = {
        p.relative_to(package).as_posix()
        for p in package.rglob("*.py")
        if re.search(r"\.savefig\(|\bdpi\s*=", p.read_text())
    }
    assert found == {"reporting.py"}


def test_load_average_is_none_where_the_os_has_none(monkeypatch):
    def fails():
        raise OSError("no load average here")

    monkeypatch.setattr(os, "getloadavg", fails)
    assert reporting.load_average() is None and reporting.load_averages() is None
    assert reporting.machine()["load_average"] is None
    monkeypatch.delattr(os, "getloadavg")
    assert reporting.load_average() is None
    assert reporting.machine()["cores"] == os.cpu_count()


def test_load_average_reads_the_os(monkeypatch):
    monkeypatch.setattr(os, "getloadavg", lambda: (1.5, 1.0, 0.5))
    assert reporting.load_average() == 1.5
    assert reporting.machine()["load_average"] == [1.5, 1.0, 0.5]


def test_the_gpu_is_stamped_where_torch_sees_one(monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert reporting.machine()["gpu"] is None and "GPU" not in reporting.machine_line()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a: "NVIDIA H100 80GB HBM3")
    assert reporting.machine()["gpu"] == "NVIDIA H100 80GB HBM3"
    assert reporting.machine_line().endswith(" cores, GPU NVIDIA H100 80GB HBM3")


def test_versions_start_with_the_package():
    found = reporting.versions("numpy")
    assert list(found) == ["slungload", "numpy"] and found["slungload"] == slungload.__version__


def test_model_colors_are_stable_per_label_and_distinct_within_a_figure():
    assert reporting.PHYSICS_LABEL == PHYSICS
    labels = [PHYSICS, "proposed", "no-slack", "no-physics", "physics-step/no-physics"]
    colors = reporting.model_colors(labels)
    assert colors[PHYSICS] == reporting.PHYSICS_COLOR
    networks = [colors[la] for la in labels[1:]]
    assert len(set(networks)) == len(networks) and reporting.PHYSICS_COLOR not in networks
    # A label's colour does not depend on the labels after it, nor on the process.
    assert reporting.model_colors(labels[:2]) == {la: colors[la] for la in labels[:2]}
    assert reporting.model_colors(["proposed", "x"])["proposed"] == colors["proposed"]
    # Past the palette, colours repeat rather than fail.
    many = reporting.model_colors(f"run-{i}" for i in range(20))
    assert len(set(list(many.values())[:9])) == 9 and len(many) == 20


@pytest.mark.parametrize("label", ["proposed", "physics-step/no-physics", "ps-exc"])
def test_model_color_is_a_palette_colour(label):
    assert reporting.model_colors([label])[label] in reporting.MODEL_COLORS


def test_mean_std_is_the_mean_the_sample_std_and_the_count():
    mean, std, n = reporting.mean_std([1.0, 2.0, 3.0, 4.0])
    assert (mean, n) == (2.5, 4) and std == pytest.approx(math.sqrt(5 / 3), rel=1e-15)
    values = [0.1234, 0.5678, 0.9012]  # the digits a report prints: statistics' own
    assert reporting.mean_std(values) == (statistics.fmean(values), statistics.stdev(values), 3)
    assert reporting.mean_std(v for v in (2.0, 4.0)) == (3.0, math.sqrt(2.0), 2)  # any iterable


def test_mean_std_of_one_value_has_no_spread():
    assert reporting.mean_std([0.731]) == (0.731, 0.0, 1)


def test_write_csv_round_trips_through_the_csv_module(tmp_path):
    rows = [["physics", None, 50, 0.1 + 0.2, math.inf], ["a, b", 3, 25, 1e-7, 'x"y']]
    header = ["label", "seed", "N", "rmse", "e"]
    path = reporting.write_csv(tmp_path / "sub" / "t.csv", header, rows)
    assert path == tmp_path / "sub" / "t.csv"
    text = path.read_text()
    assert text.splitlines()[1] == "physics,,50,0.30000000000000004,inf" and "\r" not in text
    with open(path, newline="") as f:
        read = list(csv.reader(f))
    assert read[0] == header
    assert read[1] == ["physics", "", "50", repr(0.1 + 0.2), "inf"]
    assert read[2][0] == "a, b" and float(read[2][3]) == 1e-7 and read[2][4] == 'x"y'
    assert [p.name for p in path.parent.iterdir()] == ["t.csv"]  # no temporary file left
    assert reporting.write_csv(tmp_path / "h.csv", ["only"], []).read_text() == "only\n"


def test_write_csv_leaves_the_old_file_when_a_row_cannot_be_written(tmp_path):
    class Unwritable:
        def __str__(self) -> str:
            raise ValueError("no text for this cell")

    path = reporting.write_csv(tmp_path / "t.csv", ["a", "b"], [[1, 2.5]])
    before = path.read_bytes()
    with pytest.raises(ValueError, match="no text"):
        reporting.write_csv(path, ["a", "b"], [[3, 4.5], [Unwritable(), 1]])
    assert path.read_bytes() == before == b"a,b\n1,2.5\n"
    assert [p.name for p in tmp_path.iterdir()] == ["t.csv"]
