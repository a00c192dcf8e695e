"""The virtual controller: a simulated GRBL-like machine, its real-time runner, fault injection."""
