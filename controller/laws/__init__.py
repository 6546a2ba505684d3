"""Control laws over arrays of candidates (shape ``(B,)``); the live loop is the batch of one.

Every law has frozen-dataclass parameters with array fields, a separate state
value, an ``init`` giving the state and a pure ``step(params, state, ...) ->
(state, output)``.
"""
