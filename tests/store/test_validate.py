"""The store's boundary checks on numbers: a NumPy scalar (what the engine hands over) is a
number; a bool, a string or a non-finite value is refused, naming the field."""

from __future__ import annotations

import numpy as np
import pytest

from sessions.store.errors import StoreValueError
from sessions.store.validate import number


@pytest.mark.parametrize("value", [np.float32(1.5), np.float64(1.5), np.int64(3), 2, 2.5])
def test_numbers_of_any_real_kind_are_accepted_as_floats(value: object) -> None:
    x = number("optimum_w", value)
    assert type(x) is float and x == float(value)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("value", "reason"),
    [(True, "must be a number"), ("1", "must be a number"), (np.bool_(True), "must be a number"),
     (float("nan"), "must be finite"), (np.float64("inf"), "must be finite"), (1 + 2j, "must be")],
)  # fmt: skip
def test_what_is_not_a_finite_real_is_refused_naming_the_field(value: object, reason: str) -> None:
    with pytest.raises(StoreValueError, match=f"optimum_w: {reason}"):
        number("optimum_w", value)


def test_bounds_name_the_limit() -> None:
    with pytest.raises(StoreValueError, match="optimum_w: must be greater than 0"):
        number("optimum_w", np.float64(0.0), gt=0.0)
