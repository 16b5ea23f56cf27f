"""``monoflow-train --help``: instant (no torch import), and the same flags as the real parser."""

from __future__ import annotations

import subprocess
import sys

from _trainer_fixtures import REPO, child_env


def test_help_does_not_import_torch():
    code = ("import sys\nfrom training.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit as e:\n"
            "    assert e.code == 0\nprint('TORCH_LOADED', 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=child_env(), capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    assert "TORCH_LOADED False" in out.stdout
    for flag in ("--resume", "--threads", "--sync_bn", "--data.workers", "--model.width_scale", "--loss.beta",
                 "--optim.decay_every_samples"):
        assert flag in out.stdout


def test_help_parser_equals_the_real_parser():
    from training.cli import build_help_parser, build_parser

    def table(parser):
        return {a.dest: (tuple(a.option_strings), a.help) for a in parser._actions}

    real, light = table(build_parser()), table(build_help_parser())
    assert real == light
    assert real["model.level_points"][1] == "points and set-conv neighbours at L0..L4. (default: 2048,1024,256,64,16)"
    assert real["loss.alpha_order"][1].endswith("(default: released)") and "α1" in real["loss.alpha_order"][1]
    assert build_parser().format_help() == build_help_parser().format_help()
