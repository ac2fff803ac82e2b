"""A disjoint-set forest (union–find) over hashable nodes, for grouping tracks into connected components."""

from __future__ import annotations

from collections.abc import Hashable
from typing import Generic, TypeVar

N = TypeVar("N", bound=Hashable)


class DisjointSet(Generic[N]):
    """Union–find with path halving; a node joins the forest the first time it is named."""

    def __init__(self) -> None:
        self._parent: dict[N, N] = {}

    def find(self, node: N) -> N:
        """The representative of ``node``'s set."""
        parent = self._parent
        parent.setdefault(node, node)
        while parent[node] != node:
            parent[node] = parent[parent[node]]
            node = parent[node]
        return node

    def union(self, a: N, b: N) -> None:
        """Merge the sets of ``a`` and ``b``."""
        self._parent[self.find(a)] = self.find(b)

    def nodes(self) -> list[N]:
        """Every node named so far, in the order first named."""
        return list(self._parent)
