"""Speed-against-error benchmark harness and report."""
