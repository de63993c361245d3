"""bentray bench: error against run time, tables and plots."""
