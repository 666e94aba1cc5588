"""The composition root: live and simulated runs wired from arguments and the field config.

Everything that builds devices (Modbus, HTTP cameras, the simulated plant), drives a clock
(APScheduler on the plant clock, or the virtual clock), draws on a terminal or attaches the web
console lives here; the campaign core below it only sees device protocols and plain state."""
