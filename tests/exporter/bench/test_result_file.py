"""The benches' one JSON writer: the folder is made, the file reads back, and no --json writes nothing."""
from __future__ import annotations

import json

from exporter.bench.result_file import write_result


def test_the_result_is_written_where_asked_and_said(tmp_path, capsys):
    out = tmp_path / "new" / "folder" / "bench.json"
    write_result(out, {"rows": [{"p50_ms": 1.5}], "cpu": "x"})
    assert json.loads(out.read_text()) == {"rows": [{"p50_ms": 1.5}], "cpu": "x"}
    assert out.read_text().endswith("}\n") and f"wrote {out}" in capsys.readouterr().out


def test_no_path_writes_nothing(tmp_path, capsys):
    write_result(None, {"rows": []})
    assert list(tmp_path.iterdir()) == [] and capsys.readouterr().out == ""
