"""Light stage driver: wire protocol, serial link, firmware simulator and the driver node."""
