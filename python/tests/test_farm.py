"""The Dask farm example: workers in separate processes, merged in the order they finish,
give the bytes of one process recording every sample."""

import os
import sys

import pytest

distributed = pytest.importorskip("dask.distributed")
cloudpickle = pytest.importorskip("cloudpickle")

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "examples"))
import dask_farm  # noqa: E402

# The workers cannot import the example by name: ship its functions by value.
cloudpickle.register_pickle_by_value(dask_farm)


def test_a_farm_of_processes_trains_the_bytes_one_process_trains():
    iterations, shards, samples = 3, 5, 20_000
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        farm = dask_farm.train_on_farm(client, iterations, shards, samples)
    one = dask_farm.train_in_one_process(iterations, shards, samples)
    assert farm == one
    field = dask_farm.sdguide.GuidingField.from_bytes(farm)
    stats = field.stats()
    assert stats["iteration"] == iterations and stats["spatial_leaves"] > 1
