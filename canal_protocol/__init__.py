"""The contract between Canal's service and its clients.

Request and response models (:mod:`canal_protocol.schemas`), the fit options derived from
canal_core (:mod:`canal_protocol.options`) and the live wire codecs
(:mod:`canal_protocol.wire`). Both the service and the client depend on this package and
never on each other; this package depends only on :mod:`canal_core`, pydantic and orjson
(the ``protocol`` extra).
"""
