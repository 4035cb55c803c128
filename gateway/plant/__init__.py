"""The machine around the cell: plant models, and the faults an engineer rehearses
(docs/plant.md).  A source of inputs like the PLC scan -- through the door, never a back door
into the image."""

from ncgate.gateway.plant.plant import ActiveFault, Plant

__all__ = ["ActiveFault", "Plant"]
