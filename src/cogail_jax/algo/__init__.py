"""The algorithm: the typed config (:mod:`.config`), networks, losses, the rollout and the jitted train step."""
