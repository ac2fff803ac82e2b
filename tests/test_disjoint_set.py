"""Union–find agrees with a breadth-first search of the same graph."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from rig.analysis.disjoint_set import DisjointSet


def _components_by_search(nodes: set[int], edges: list[tuple[int, int]]) -> set[frozenset[int]]:
    neighbours: dict[int, set[int]] = {n: set() for n in nodes}
    for a, b in edges:
        neighbours[a].add(b)
        neighbours[b].add(a)
    seen: set[int] = set()
    out = set()
    for start in nodes:
        if start in seen:
            continue
        comp, frontier = {start}, [start]
        while frontier:
            for nxt in neighbours[frontier.pop()] - comp:
                comp.add(nxt)
                frontier.append(nxt)
        seen |= comp
        out.add(frozenset(comp))
    return out


@given(st.lists(st.tuples(st.integers(0, 30), st.integers(0, 30)), max_size=60))
def test_union_find_components_match_a_graph_search(edges: list[tuple[int, int]]) -> None:
    sets = DisjointSet()
    for a, b in edges:
        sets.union(a, b)
    groups: dict[object, set[int]] = {}
    for node in sets.nodes():
        groups.setdefault(sets.find(node), set()).add(node)
    nodes = {n for e in edges for n in e}
    assert {frozenset(g) for g in groups.values()} == _components_by_search(nodes, edges)
