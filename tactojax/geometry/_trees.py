"""Indexing batched pytrees (poses, beliefs, touches) along their leading axes."""

from __future__ import annotations

import jax


def take(tree, index):
    """``tree`` with every leaf indexed by ``index`` (an int, a slice or an index array).

    For a batched :class:`jaxlie.SE3` of shape (N,), ``take(T, i)`` is the i-th pose and
    ``take(T, idx)`` the (M,) poses at ``idx``; the same for any pytree of arrays sharing
    their leading axes (a :class:`~tactojax.localize.PoseBelief`, a test episode).
    """
    return jax.tree.map(lambda x: x[index], tree)
