"""The machines at work: one supervised task per machine that connects, polls, listens and runs
its due jobs (:mod:`.tasks`), programs a control sends by itself and its remote requests
(:mod:`.remote_request`, decided by the actions' policy), and every machine's status on every
server of a cluster (:mod:`.shared_status`).

It may import the packages under it, the actions included.
"""
