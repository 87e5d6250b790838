"""The networks, one file each with its config: no noise process, no sampling."""
