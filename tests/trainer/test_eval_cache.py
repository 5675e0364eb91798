"""The stored scores' key follows the scoring code and only it: the static import closure of the scorer."""
from __future__ import annotations

from pathlib import Path

from trainer.eval_cache import ROOT, _code_hash, scoring_files


def _tree(base: Path) -> None:
    files = {
        "trainer/__init__.py": "",
        "trainer/score.py": "import json\n\ndef run():\n    from trainer.helper import f   # a function-level import\n"
                            "    return f()\n",
        "trainer/helper.py": "from kiosk.contract import rules\n\ndef f():\n    return rules.X\n",
        "trainer/train_only.py": "import trainer.score\n",
        "kiosk/__init__.py": "",
        "kiosk/contract/__init__.py": "",
        "kiosk/contract/rules.py": "X = 1\n",
    }
    for name, text in files.items():
        (base / name).parent.mkdir(parents=True, exist_ok=True)
        (base / name).write_text(text)


def test_closure_follows_function_level_imports_and_skips_what_scoring_does_not_import(tmp_path):
    _tree(tmp_path)
    got = {f.relative_to(tmp_path).as_posix() for f in scoring_files(["trainer.score"], tmp_path)}
    assert got == {"trainer/__init__.py", "trainer/score.py", "trainer/helper.py", "kiosk/__init__.py",
                   "kiosk/contract/__init__.py", "kiosk/contract/rules.py"}
    key = _code_hash(scoring_files(["trainer.score"], tmp_path), tmp_path)
    (tmp_path / "trainer/train_only.py").write_text("import trainer.score\nY = 2\n")   # training side: same key
    assert _code_hash(scoring_files(["trainer.score"], tmp_path), tmp_path) == key
    (tmp_path / "kiosk/contract/rules.py").write_text("X = 2\n")                      # scoring side: new key
    assert _code_hash(scoring_files(["trainer.score"], tmp_path), tmp_path) != key


def test_the_real_scorer_closure():
    got = {f.relative_to(ROOT).as_posix() for f in scoring_files()}
    for needed in ("trainer/evaluate.py", "trainer/texture_distance.py", "trainer/metrics.py", "trainer/references.py",
                   "trainer/checkpoint.py", "trainer/models/generator.py", "trainer/models/spade_generator.py",
                   "kiosk/contract/graph.py", "trainer/eval_cache.py"):
        assert needed in got, needed
    for not_scoring in ("trainer/loop.py", "trainer/methods/ours.py", "trainer/losses/gan.py", "trainer/cli.py",
                        "trainer/compare.py", "trainer/verdict.py"):   # training side; tables built from scores
        assert not_scoring not in got, not_scoring
