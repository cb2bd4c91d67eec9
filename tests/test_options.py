"""BindOptions: defaults, every bad value refused with one CageError naming all of them, and bind() refusing bad
options before any meshing."""

import dataclasses
import math

import numpy as np
import pytest

import lbc_core
from lbc_core.solve import forecast
from lbc_core.errors import CageError
from lbc_core import BindOptions
from lbc_core.binding.options import WEIGHTINGS
from lbc_core.binding.pipeline import request_of
from lbc_core.evaluate.smoothing import DEFAULT_SMOOTHNESS

SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def test_defaults():
    options = BindOptions()
    assert options.weighting == "quadratic" and options.epsilon == 0.0 and options.method == "auto"
    assert options.max_iterations == 10000
    assert options.cells is None and options.threshold is None and options.tolerance is None
    assert options.threshold_for(4) == 1e-3 / 4
    assert options.smoothness == DEFAULT_SMOOTHNESS == 0.5
    assert BindOptions(**{field.name: None for field in dataclasses.fields(options)}) == options


def test_the_names_agree_with_the_stages_that_use_them():
    # The meshing stage takes DEFAULT_CELLS and METHODS from lbc_core.binding.options, the weighting names come from the
    # geodesics stage; the tolerances live beside the cost model (forecast), so their keys are checked here.
    assert WEIGHTINGS[0] == "quadratic"  # the paper's choice, the default
    assert set(forecast.DEFAULT_TOLERANCE) == {2, 3}


def test_numbers_are_normalised():
    options = BindOptions(cells=np.int64(3000), epsilon=1, threshold=np.float32(0.0), max_iterations=50.0)
    assert options.cells == 3000 and type(options.cells) is int
    assert options.epsilon == 1.0 and type(options.epsilon) is float
    assert options.max_iterations == 50 and type(options.max_iterations) is int


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("cells", "3000", "cells must be a number, got the string '3000'"),
        ("cells", math.nan, "cells must be a finite number, got nan"),
        ("cells", 0, "cells must be at least 10, got 0"),
        ("cells", -5, "cells must be at least 10, got -5"),
        ("cells", True, "cells must be a number, got True (a bool)"),
        ("cells", 3000.5, "cells must be a whole number, got 3000.5"),
        ("cells", 3 + 0j, "cells must be a real number"),
        ("weighting", "cubic", "weighting 'cubic' is not one of quadratic, linear, sqrt, constant"),
        ("weighting", 3, "weighting must be one of"),
        ("weighting", lambda d: -d, "weighting function must return finite, non-negative weights"),
        ("weighting", lambda d: d[0], "weighting function must return weights of its input's shape"),
        ("weighting", lambda d: d.nope, "weighting function failed on an array of distances"),
        ("epsilon", -0.1, "epsilon must be 0 or more, got -0.1"),
        ("epsilon", math.nan, "epsilon must be a finite number"),
        ("epsilon", math.inf, "epsilon must be a finite number"),
        ("threshold", -1e-4, "threshold must be in [0, 1/n)"),
        ("threshold", 1.0, "threshold must be in [0, 1/n)"),
        ("tolerance", 0, "tolerance must be more than 0, got 0"),
        ("tolerance", -1, "tolerance must be more than 0, got -1"),
        ("max_iterations", -5, "max_iterations must be at least 1, got -5"),
        ("max_iterations", 0, "max_iterations must be at least 1, got 0"),
        ("method", "bogus", "method 'bogus' is not one of auto, delaunay, triangle"),
        ("smoothness", -0.1, "smoothness must be in [0, 1], got -0.1"),
        ("smoothness", 1.5, "smoothness must be in [0, 1], got 1.5"),
        ("smoothness", "high", "smoothness must be a number, got the string 'high'"),
        ("evaluation", "cubic", "evaluation 'cubic' is not one of smooth, linear"),
    ],
)
def test_bad_values_are_refused(field, value, message):
    with pytest.raises(CageError) as error:
        BindOptions(**{field: value})
    assert message in str(error.value)


def test_every_bad_value_is_named_at_once():
    with pytest.raises(CageError) as error:
        BindOptions(cells=0, epsilon=-1, max_iterations=-5)
    text = str(error.value)
    assert text.startswith("bad bind options: ")
    assert "cells must be" in text and "epsilon must be" in text and "max_iterations must be" in text


def test_of_overrides_the_given_fields_and_checks_them():
    base = BindOptions(cells=500, epsilon=0.1)
    assert BindOptions.of(base, epsilon=0.2) == BindOptions(cells=500, epsilon=0.2)
    assert BindOptions.of(None, cells=None) == BindOptions()
    with pytest.raises(CageError, match="epsilon must be 0 or more"):
        BindOptions.of(base, epsilon=-1)
    with pytest.raises(CageError, match="options must be a BindOptions"):
        BindOptions.of({"cells": 500})


def test_checks_that_need_the_cage():
    with pytest.raises(CageError, match=r"threshold 0.5 would drop every weight .* 1/n = 0.25"):
        BindOptions(threshold=0.5).check_for_cage(4, 2)
    BindOptions(threshold=0.2).check_for_cage(4, 2)
    with pytest.raises(CageError, match="method 'triangle' does not mesh 3D cages: use one of auto, delaunay"):
        BindOptions(method="triangle").check_for_cage(8, 3)


@pytest.mark.parametrize(
    "options, message",
    [
        ({"cells": "3000"}, "cells must be a number"),
        ({"cells": 0}, "cells must be at least 10"),
        ({"weighting": "cubic"}, "weighting 'cubic'"),
        ({"method": "bogus"}, "method 'bogus'"),
        ({"tolerance": 0}, "tolerance must be more than 0"),
        ({"threshold": 0.5}, "threshold 0.5 would drop every weight"),
        ({"epsilon": math.nan}, "epsilon must be a finite number"),
    ],
)
def test_bind_refuses_bad_options_before_meshing(monkeypatch, options, message):
    def no_meshing(*args, **kwargs):
        raise AssertionError("meshing started with bad options")

    monkeypatch.setattr("lbc_core.binding.pipeline.mesh_domain", no_meshing)
    with pytest.raises(CageError, match=message):
        lbc_core.bind(SQUARE, None, [[0.5, 0.5]], **options)


def test_bind_takes_an_options_object_and_records_it():
    binding = lbc_core.bind(SQUARE, None, [[0.5, 0.5]], options=BindOptions(cells=200, epsilon=0.01),
                            max_iterations=500)
    assert binding.options.epsilon == 0.01 and binding.options.max_iterations == 500
    assert binding.options.weighting == "quadratic" and binding.outcome.threshold == 1e-3 / 4


def test_the_smoothness_is_recorded_and_asked_again():
    binding = lbc_core.bind(SQUARE, None, [[0.5, 0.5]], cells=200, smoothness=0.8)
    assert binding.options.smoothness == 0.8
    assert request_of(binding).smoothness == 0.8
