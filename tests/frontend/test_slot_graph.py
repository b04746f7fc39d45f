"""The frontend's covisibility graph and spanning tree over keyframe slots."""

from zenslam.frontend.slot_graph import SlotGraph


def test_parent_is_the_best_connection_and_ordering_follows_relinking():
    graph = SlotGraph(min_weight=15)
    assert graph.add({}) == 0 and graph.parent(0) == -1
    assert graph.add({0: 40}) == 1
    assert graph.add({0: 20, 1: 30}) == 2
    assert (graph.parent(1), graph.parent(2)) == (0, 1) and graph.children(1) == [2]
    assert graph.ordered(0) == [1, 2] and graph.weight(2, 0) == 20
    graph.set_links(2, {0: 50, 1: 5})  # weak links count only when no strong one exists
    assert graph.ordered(2) == [0] and graph.ordered(0) == [2, 1] and graph.weight(1, 2) == 5
    graph.set_links(2, {1: 5})
    assert graph.ordered(2) == [1] and graph.ordered(0) == [1]


def test_removing_a_slot_moves_its_children_to_its_parent():
    graph = SlotGraph(min_weight=15)
    graph.add({})
    graph.add({0: 40})
    graph.add({1: 40})
    graph.add({1: 30, 2: 20})
    graph.remove(1)
    assert (graph.parent(2), graph.parent(3)) == (0, 0) and graph.children(0) == [2, 3]
    assert graph.ordered(1) == [] and graph.weight(0, 1) == 0 and graph.ordered(3) == [2]


def test_compacting_renumbers_kept_slots_and_reattaches_orphans_to_the_nearest_kept_ancestor():
    graph = SlotGraph(min_weight=15)
    graph.add({})  # 0
    graph.add({0: 40})  # 1, parent 0
    graph.add({1: 40})  # 2, parent 1
    graph.add({0: 50, 2: 20})  # 3, parent 0
    graph.add({2: 30, 3: 16})  # 4, parent 2
    graph.compact([0, -1, -1, 1, 2])  # drop slots 1 and 2
    assert (graph.parent(0), graph.parent(1), graph.parent(2)) == (-1, 0, 0)
    assert graph.children(0) == [1, 2]  # the kept child first, then the re-attached grandchild
    assert graph.ordered(2) == [1] and graph.weight(2, 1) == 16 and graph.ordered(0) == [1]
    assert graph.add({2: 20}) == 3 and graph.parent(3) == 2
