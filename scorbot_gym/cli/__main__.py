import sys

from scorbot_gym.cli import main

sys.exit(main())
