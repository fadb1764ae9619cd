"""``predict``'s checks of its input: the observation's shape, and no NaN or inf."""

from __future__ import annotations

import numpy as np
import pytest
from soak import make_light_model


def test_predict_rejects_bad_observations(tiny_dataset: str) -> None:
    model = make_light_model(tiny_dataset).learn(3)
    assert model.predict(np.zeros(3, dtype=np.float32))[0].shape == (2,)
    assert model.predict(np.zeros((5, 3), dtype=np.float32))[0].shape == (5, 2)
    with pytest.raises(ValueError, match=r"shape \(4,\); this model expects \(3,\)"):
        model.predict(np.zeros(4, dtype=np.float32))
    with pytest.raises(ValueError, match=r"shape \(2, 2, 3\)"):
        model.predict(np.zeros((2, 2, 3), dtype=np.float32))
    bad = np.zeros((2, 3), dtype=np.float32)
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"NaN or inf \(1 values, e.g. at index \(1, 2\): nan\)"):
        model.predict(bad)
    with pytest.raises(ValueError, match="NaN or inf"):
        model.predict(np.array([0.0, np.inf, 0.0]))
