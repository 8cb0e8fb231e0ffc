"""The durable job queue (:mod:`.queue`: the only code that moves a job between states), the
runner that claims due jobs (:mod:`.runner`) and the executor of each job kind
(:mod:`.executors`).

It may import core, store, kinds, config, library and machines.
"""
