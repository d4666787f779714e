"""The shared geometry: entity columns, the distance matrix and nearest-slot selection."""

from __future__ import annotations

import numpy as np
from sim_helpers import geometry_of, make_state

from terl_rt.sim.geometry import SlotGroup, candidate_key, nearest_slots, per_entity

INF = np.inf


def test_distance_matrix_rows_are_robots_and_columns_every_entity_then_the_blank():
    state = make_state(
        pursuers=[[0.0, 0.0, 0.0, 0.0], [3.0, 4.0, 0.0, 0.0]],
        evaders=[[0.0, 10.0, 0.0, 0.0]],
        obstacles=[[6.0, 8.0, 1.0]],
    )
    geometry = geometry_of(state)
    assert geometry.distance.shape == (1, 3, 5)  # 2 + 1 robots; 2 + 1 + 1 entities + blank
    np.testing.assert_allclose(geometry.distance[0, 0], [0.0, 5.0, 10.0, 10.0, 0.0])
    np.testing.assert_allclose(geometry.pursuer_evader[0], [[10.0], [np.hypot(3.0, 6.0)]])
    np.testing.assert_allclose(geometry.evader_obstacle[0], [[np.hypot(6.0, 2.0)]])
    assert geometry.entity_z[0, -1] == 0.0 and geometry.num_entities == 4


def test_nearest_slots_sorts_each_group_apart_and_pads_with_the_blank():
    # Columns: 3 "teammates", 1 "evader", blank (4). Row 0 sees teammates 2 and 0.
    key = np.array([[[3.0, INF, 1.0, 7.0, INF]]])
    groups = (SlotGroup(0, 3, 2), SlotGroup(3, 4, 3))
    columns = nearest_slots(key, groups)
    assert columns.tolist() == [[[2, 0, 3, 4, 4]]]


def test_nearest_slots_keeps_only_the_k_nearest_of_a_large_group():
    key = np.array([[[5.0, 4.0, 3.0, 2.0, 1.0, 0.5, INF]]])
    assert nearest_slots(key, (SlotGroup(0, 6, 3),)).tolist() == [[[5, 4, 3]]]


def test_candidate_key_drops_oneself_and_entities_beyond_their_limit():
    distance = np.array([[[0.0, 2.0, 9.0, 0.0], [2.0, 0.0, 1.0, 0.0]]])  # rows: robots 0 and 1
    limit = per_entity(np.array([[5.0, 5.0]]), np.zeros((1, 0)), np.array([[1.5]]), blank=-1.0)
    assert limit.tolist() == [[5.0, 5.0, 1.5, -1.0]]
    key = candidate_key(distance, 0, limit)
    assert key.tolist() == [[[INF, 2.0, INF, INF], [2.0, INF, 1.0, INF]]]
    # Rows of later robots (first_row 1): robot 1 is column 1.
    assert candidate_key(distance[:, 1:], 1, limit).tolist() == [[[2.0, INF, 1.0, INF]]]
