"""The interface contract in code: topic names and message types (:mod:`.topics`), QoS profiles
(:mod:`.qos`), message fields and frames (:mod:`.conversions`), the vectorized CDR codec (:mod:`.cdr`)."""
