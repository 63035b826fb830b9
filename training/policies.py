"""An SB3 actor-critic policy whose critic learns at its own rate.

SB3 trains actor and critic with one Adam optimizer at one learning rate.
A residual policy on a tuned controller needs a small actor step (Balance:
1e-4, formerly 3e-5; at 2.5e-4 the residual wrecked the standing PD within
minutes), and
with the actor and critic in separate networks Adam's step per parameter is
about the learning rate whatever ``vf_coef`` scales the value loss by, so
the critic fits at that small rate too. ``critic_lr_factor`` (in
``policy_kwargs``) lets the critic step at a multiple of the (scheduled)
learning rate; what it changed for Balance is in ``docs/balance_training.md``.
Saved models name this class by its module path (``training.policies``),
which must stay where it is for them to load.
"""

from __future__ import annotations

import torch
from stable_baselines3.common.policies import ActorCriticPolicy


class GroupScaledAdam(torch.optim.Adam):
    """Adam whose parameter groups step at the learning rate times their
    ``lr_factor``. SB3 sets every group's ``lr`` from its schedule before each
    update; the factor is applied inside ``step`` only, so the groups' ``lr``
    read (and are logged) as the schedule's."""

    def step(self, closure=None):
        scheduled = [group["lr"] for group in self.param_groups]
        for group in self.param_groups:
            group["lr"] = group["lr"] * group.get("lr_factor", 1.0)
        try:
            return super().step(closure)
        finally:
            for group, lr in zip(self.param_groups, scheduled):
                group["lr"] = lr


class CriticRatePolicy(ActorCriticPolicy):
    """``MlpPolicy`` with the critic (its value layers and value head) in its
    own Adam parameter group stepping at ``critic_lr_factor`` times the
    learning rate; the actor, its log std and any shared layers at the
    learning rate itself (a value-side features extractor of its own, with
    ``share_features_extractor=False``, stays with the actor: the default
    flatten extractor has no parameters). Saved and loaded like any SB3
    policy: ``PPO.load`` builds it from the saved ``policy_kwargs``, so with
    the same groups, and restores the optimizer's state into them."""

    def __init__(self, *args, critic_lr_factor: float = 1.0, **kwargs):
        try:
            factor = float(critic_lr_factor)
        except (TypeError, ValueError):
            factor = float("nan")
        if not factor > 0.0 or factor == float("inf"):
            raise ValueError(f"critic_lr_factor must be a positive finite number, got {critic_lr_factor!r}")
        optimizer_class = kwargs.get("optimizer_class", torch.optim.Adam)
        if optimizer_class is not torch.optim.Adam:
            raise ValueError(f"critic_lr_factor needs the default Adam optimizer, not {optimizer_class!r}")
        self._critic_lr_factor = factor  # read by _build, which the base class's __init__ calls
        super().__init__(*args, **kwargs)

    @property
    def critic_lr_factor(self) -> float:
        """The critic group's factor as the optimizer holds it (restored with its state on load)."""
        return float(self.optimizer.param_groups[1]["lr_factor"])

    def critic_parameters(self) -> list:
        """The value layers' and the value head's parameters."""
        return [*self.mlp_extractor.value_net.parameters(), *self.value_net.parameters()]

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        critic_ids = {id(p) for p in self.critic_parameters()}
        rest = [p for p in self.parameters() if id(p) not in critic_ids]
        self.optimizer = GroupScaledAdam([{"params": rest, "lr_factor": 1.0},
                                          {"params": self.critic_parameters(), "lr_factor": self._critic_lr_factor}],
                                         lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        data["critic_lr_factor"] = self._critic_lr_factor
        return data
