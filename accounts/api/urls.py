"""Routes of the customer and service-class endpoints, and of a user's API tokens and
webhooks."""

from rest_framework.routers import SimpleRouter

from accounts.api.members import InviteViewSet, MemberViewSet
from accounts.api.tokens import ApiTokenViewSet
from accounts.api.views import CustomerViewSet, ServiceClassViewSet
from accounts.api.webhooks import WebhookViewSet

router = SimpleRouter()
router.register("customers", CustomerViewSet, basename="customer")
router.register("service-classes", ServiceClassViewSet, basename="service-class")
router.register("tokens", ApiTokenViewSet, basename="api-token")
router.register("webhooks", WebhookViewSet, basename="webhook")
router.register("members", MemberViewSet, basename="member")
router.register("invites", InviteViewSet, basename="invite")

urlpatterns = router.urls
