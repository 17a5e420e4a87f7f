"""Where frames come from: the frame types, drivers, pairing by time, queues and recordings."""
