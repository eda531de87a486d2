"""The hardware-abstraction layer: wire protocol, CAN and serial links, record and replay."""
