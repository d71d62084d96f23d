"""Gateway: masters the network, decodes the skin and EMG streams, closes the loop."""
