"""What the node's markers show, without ROS: :mod:`.shapes` (the fish of ``model: fish`` flocks, computed by a
compiled kernel into the marker's buffer) and :mod:`.detail` (the level of detail for big flocks: how the fish
are drawn, how often they are redrawn, how often the bag records the flocks' poses)."""
