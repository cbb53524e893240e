"""The tools above the services (architecture rule 9): the command line, the report, the Foxglove bridge, the local
stack runner and the Monte-Carlo runner. They reach estimators only through the plugin registry; nothing below
imports them."""
