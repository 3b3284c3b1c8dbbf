from miktcli.cli.app import main

main()
