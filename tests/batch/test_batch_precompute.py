"""The rig precompute made once and shared: a Pipeline on it uses it as it is (no model built,
no pattern factored) and solves exactly as a Pipeline that made its own, also after pickling
(what a worker receives)."""

import pickle

import numpy as np
import pytest

from puppet.bus import Reading
from puppet.fast import FastError
from puppet.loop import Pipeline, RigPrecompute


def test_a_pipeline_on_a_shared_precompute_solves_as_one_that_made_its_own(critter):
    precompute = RigPrecompute.for_rig(critter)
    received = pickle.loads(pickle.dumps(precompute))
    assert precompute.nbytes() == len(pickle.dumps(precompute, protocol=pickle.HIGHEST_PROTOCOL))
    k = len(critter.servo_map)
    readings = [Reading(i, critter.servo_map.ids,
                        (critter.servo_map.zero + 300 * np.sin(0.3 * i + np.arange(k))).astype(np.int32),
                        np.ones(k, bool)) for i in range(5)]
    with Pipeline(critter, render=False) as own, \
            Pipeline(critter, render=False, precompute=received) as shared:
        assert shared.model is received.model
        assert shared.solver.factor is received.factor
        for reading in readings:
            assert np.array_equal(own.solve(reading), shared.solve(reading))


def test_a_precompute_of_another_size_is_refused(critter):
    precompute = RigPrecompute.for_rig(critter)
    model = precompute.model
    wrong = type(precompute.factor)(G=precompute.factor.G, P2=precompute.factor.P2,
                                    H=np.zeros((8, 8)))
    with pytest.raises(FastError) as caught:
        model.solver(critter.pattern(), factor=wrong)
    assert "a shared factor fits a model of 2 handles" in str(caught.value)
