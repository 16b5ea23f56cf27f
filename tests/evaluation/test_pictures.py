"""Pictures: direction colours, training curves from a run folder's CSV files (``monoflow-evaluate curves``)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")


def test_direction_colours_encode_direction_and_length():
    from evaluation.pictures import direction_colours

    c = direction_colours(np.array([[1.0, 0.0], [-1.0, 0.0], [0.1, 0.0], [0.0, 5.0]]), max_length=1.0)
    assert np.argmax(c[0]) == 0  # right = red
    assert c[1][0] < 0.2 and c[1][1] > 0.8 and c[1][2] > 0.8  # left = cyan
    assert c[2].max() < c[0].max()  # shorter = darker, same hue
    assert np.allclose(c[3].max(), 1.0)  # clipped at full brightness


def test_curves_from_a_run_folder(tmp_path, capsys):
    from evaluation.cli import main

    run = tmp_path / "run"
    run.mkdir()
    steps = np.arange(1, 21)
    rows = ["step,lr,loss,l0/depth,l0/chamfer,l0/weighted,l1/depth,total,grad_norm"]
    rows += [f"{s},0.001,{2 / s:.4f},{1 / s:.4f},{0.5 / s:.4f},0.1,0.2,{2 / s:.4f},1.0" for s in steps]
    (run / "train.csv").write_text("\n".join(rows) + "\n")
    (run / "val.csv").write_text("step,val_epe3d,val_loss\n0,0.8,1.1\n10,0.5,0.9\n20,0.4,0.8\n")
    assert main(["curves", str(run)]) == 0
    png = run / "curves.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert main(["curves", str(tmp_path / "empty_dir")]) == 2
    assert "train.csv" in capsys.readouterr().err
