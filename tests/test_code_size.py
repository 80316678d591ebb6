"""Modules and functions at human scale: ``tools/code_size.py`` on ``jaximpact`` and
``fitting``, no module above 600 lines, no function above 80, no import circle."""

import importlib.util
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parent.parent / "tools" / "code_size.py"


def code_size():
    spec = importlib.util.spec_from_file_location("code_size", TOOL)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("package", ["jaximpact", "fitting"])
def test_modules_and_functions_within_the_limits(package, capsys):
    problems = code_size().check(package)
    out = capsys.readouterr().out
    assert "the 5 largest modules" in out and "the 5 longest functions" in out
    assert not problems, "\n".join(problems)


def test_the_tool_exits_1_over_a_limit(monkeypatch, capsys):
    tool = code_size()
    monkeypatch.setattr(tool, "FUNCTION_LINES", 5)
    assert tool.main(["--package", "jaximpact"]) == 1
    assert "over the limits" in capsys.readouterr().out
