"""A disjoint-set forest (union–find) over hashable nodes, for grouping tracks into connected components."""

from __future__ import annotations

from collections.abc import Hashable


class DisjointSet:
    """Union–find with path halving; a node joins the forest the first time it is named."""

    def __init__(self) -> None:
        self._parent: dict[Hashable, Hashable] = {}

    def find(self, node: Hashable) -> Hashable:
        """The representative of ``node``'s set."""
        parent = self._parent
        parent.setdefault(node, node)
        while parent[node] != node:
            parent[node] = parent[parent[node]]
            node = parent[node]
        return node

    def union(self, a: Hashable, b: Hashable) -> None:
        """Merge the sets of ``a`` and ``b``."""
        self._parent[self.find(a)] = self.find(b)

    def nodes(self) -> list[Hashable]:
        """Every node named so far, in the order first named."""
        return list(self._parent)
