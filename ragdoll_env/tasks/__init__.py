"""The tasks: scene, observation, reward and termination, batched over worlds."""
from .balance import BalanceTask
from .base import Task
from .inverted_double_pendulum import InvertedDoublePendulumTask
from .inverted_pendulum import InvertedPendulumTask

#: registered id -> task class
TASKS = {
    InvertedPendulumTask.env_id: InvertedPendulumTask,
    InvertedDoublePendulumTask.env_id: InvertedDoublePendulumTask,
    BalanceTask.env_id: BalanceTask,
}


def task_class(task):
    """A task class from a class, an instance's class, or a registered id (with or without "Ragdoll/")."""
    if isinstance(task, type) and issubclass(task, Task):
        return task
    if isinstance(task, str):
        key = task.split(":")[-1]
        if key in TASKS:
            return TASKS[key]
        if "Ragdoll/" + key in TASKS:
            return TASKS["Ragdoll/" + key]
        raise ValueError(f"unknown task {task!r}; tasks: {sorted(TASKS)}")
    raise TypeError(f"expected a Task subclass or a task id, got {task!r}")
