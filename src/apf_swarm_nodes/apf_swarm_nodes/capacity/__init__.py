"""What this machine carries: its identity and costs, and the capacity probe that measures them."""
