"""Distillation of retrieval features: a small student ranks imprints as a large teacher does.

CTI retrieval (paper section VI) only uses which stored imprints are most similar to a touch,
so the student is not asked to reproduce the teacher's feature vectors (1280 numbers for
ImageNet EfficientNet-Lite0) but its *neighbourhoods*: over a batch of views, the softmax of
each view's cosine similarities to the others under the teacher (at ``teacher_temperature``)
is the target of the student's softmax (at ``temperature``), a relational distillation
(Park et al. 2019, "Relational Knowledge Distillation"; Tung & Mori 2019, "Similarity-Preserving
Knowledge Distillation"). The teacher's features are computed once per imprint, before
training, on the clean images; the student sees augmented views of them, so it also learns to
ignore what the augmentation changes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def distillation_loss(
    features: Float[Array, "B F"],
    teacher_features: Float[Array, "B T"],
    temperature: float,
    teacher_temperature: float,
) -> Float[Array, ""]:
    """Mean over views of KL(teacher neighbours || student neighbours) within a batch.

    For view i, ``p_i = softmax_{j != i}(t_i . t_j / teacher_temperature)`` and
    ``q_i = softmax_{j != i}(f_i . f_j / temperature)``; the loss is
    ``mean_i sum_j p_ij (log p_ij - log q_ij)``, zero when the student's neighbourhoods equal the
    teacher's.

    Args:
        features: (B, F) unit student features.
        teacher_features: (B, T) unit teacher features of the same views.
        temperature: student softmax temperature.
        teacher_temperature: teacher softmax temperature (teacher cosines of tactile imprints are
            close to one another, so usually smaller).
    """
    count = features.shape[0]
    off_diagonal = ~jnp.eye(count, dtype=bool)

    def log_neighbours(x, tau):
        logits = jnp.where(off_diagonal, x @ x.T / tau, -1e9)
        return logits - jax.nn.logsumexp(logits, axis=1, keepdims=True)

    log_p = log_neighbours(jax.lax.stop_gradient(teacher_features), teacher_temperature)
    log_q = log_neighbours(features, temperature)
    p = jnp.exp(log_p)
    return jnp.mean(jnp.sum(jnp.where(off_diagonal, p * (log_p - log_q), 0.0), axis=1))
