"""The learning engine: PPO (the one engine every method runs on), its networks and parameters, policies,
episodes, and seeds trained together."""
