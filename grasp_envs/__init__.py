"""The thesis' MuJoCo arm tasks as Gymnasium environments (registered on import)."""
