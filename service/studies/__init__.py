"""Studies that regenerate the committed reports; nothing in the runtime imports them."""
