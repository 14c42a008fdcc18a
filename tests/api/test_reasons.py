"""Reasons shown to people are one clean line (issue 12.6: ``/machine`` showed viewers a
multi-line pydantic error): a real ValidationError's text, as a worker's internal error
carries it, becomes ``loc: msg`` pairs; nothing else changes."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from server.service.reasons import MAX_CHARS, one_line
from sessions.config import SessionConfig


def _pydantic_text() -> str:
    with pytest.raises(ValidationError) as info:
        SessionConfig.model_validate({"duration": -1, "seeker": {"bracket": [3, 2, 1]}})
    return f"internal error: ValidationError: {info.value}"


def test_a_pydantic_error_becomes_one_line_of_loc_and_reason() -> None:
    raw = _pydantic_text()
    assert raw.count("\n") >= 4 and "errors.pydantic.dev" in raw  # what viewers saw
    line = one_line(raw)
    assert line is not None and "\n" not in line
    assert line.startswith("internal error: ValidationError: ")
    assert "duration: Input should be greater than 0" in line
    assert "seeker.bracket: " in line and "γ1 < γ2 < γ3" in line
    assert "[type=" not in line and "input_value" not in line and "pydantic.dev" not in line


def test_plain_reasons_pass_as_they_are() -> None:
    assert one_line(None) is None
    assert one_line("worker died (exit code -9)") == "worker died (exit code -9)"
    assert one_line("first\n\nsecond") == "first; second"
    assert len(one_line("x" * 5000) or "") == MAX_CHARS
