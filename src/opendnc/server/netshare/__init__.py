"""The hybrid net share: one NAS folder fanned out to the machines' own shares (:mod:`.share`),
and what its folders hold as people look at them (:mod:`.files`); the FTP server for boards
that are FTP clients (:mod:`.ftpserver`, docs/files.md).

It may import the packages under it (core to jobs); what may reach a share is decided by the
actions' policy, handed to it as a gate when the server is built.
"""
