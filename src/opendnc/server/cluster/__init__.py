"""Several servers on one PostgreSQL database (:mod:`.cluster`: leases taken and handed over,
duties run by one holder), or one server alone (:mod:`.single_server`).

It may import the packages under it (core to outputs).
"""
