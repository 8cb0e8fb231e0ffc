"""Who may do what: users, roles, passwords and API keys (:mod:`.auth`), when each key was last
used (:mod:`.key_use`), slowing down guessing (:mod:`.throttle`) and the refused attempts
summed into the audit trail (:mod:`.refusals`).

It may import core, store and config.
"""
