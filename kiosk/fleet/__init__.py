"""Fleet updates over The Update Framework: the operator publishes bundles to a TUF repository, kiosks sync.

`layout` (names, custom metadata, rollout buckets) is shared by both sides; `repo` and `keys` are the publisher
(operator's machine); `sync` and `state` run on the kiosk (its settings are the `fleet` section of kiosk.yaml). Only `repo`, `keys` and `sync` import tuf.
"""
