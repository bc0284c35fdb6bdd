from django.urls import path

from missions import views

urlpatterns = [
    path("", views.home, name="home"),
    path("vvs/<uuid:vv_id>/", views.vv_detail, name="vv-detail"),
]
